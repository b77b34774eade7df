// split.h: DC4GS' split records as the kernels read them: a Gaussian's split-geometry row (the GEO record,
// statistics.geometry_record, from split_geometry.cl) and the totals a SUM row holds in the split lanes' order
// (SPLIT_<LANE>, statistics.SPLIT_LANES). The offsets are -D options from dc4gs_cl/statistics.py.

#ifndef DC4GS_SPLIT_H
#define DC4GS_SPLIT_H

// A split-geometry row (statistics.geometry_record, GEO_*) whose view gives the Gaussian a split line.
#define HAS_SPLIT_LINE(geo) ((geo)[GEO_DIR] != 0.f || (geo)[GEO_DIR + 1] != 0.f)

// SPLIT_TOTAL_AT(v): the SUM field holding split lane v's total over all the pair's (or view's) pixels, from its dc
// sums (u_x, u_y, count) and abs sums; SPLIT_TOTALS: total[SPLIT_WIDTH], a SUM row's totals in the split lanes'
// order (SPLIT_<LANE>, statistics.SPLIT_LANES): a side's sums are a candidate's left sums or these totals minus them.
#define SPLIT_TOTAL_AT(v) ((v) == SPLIT_UX ? SUM_DC : (v) == SPLIT_UY ? SUM_DC + 1 : (v) == SPLIT_COUNT ? SUM_DC + 2 \
                           : (v) == SPLIT_ABS_X ? SUM_ABS : SUM_ABS + 1)
#define SPLIT_TOTALS(total, row)                                                                   \
    float total[SPLIT_WIDTH];                                                                      \
    total[SPLIT_UX] = (row)[SPLIT_TOTAL_AT(SPLIT_UX)]; total[SPLIT_UY] = (row)[SPLIT_TOTAL_AT(SPLIT_UY)];      \
    total[SPLIT_COUNT] = (row)[SPLIT_TOTAL_AT(SPLIT_COUNT)];                                        \
    total[SPLIT_ABS_X] = (row)[SPLIT_TOTAL_AT(SPLIT_ABS_X)];                                        \
    total[SPLIT_ABS_Y] = (row)[SPLIT_TOTAL_AT(SPLIT_ABS_Y)]   /* constant indices (a loop here: 13% slower) */

#endif
