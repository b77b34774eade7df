// split_walk.h: DC4GS' split sums as the rasterizer backward's walk gathers them (rasterize_backward.cl, -D
// SPLIT_CANDIDATES > 0): which candidates a pair's pixels cross (crossing_range), a pair's candidate line
// (candidate_line), a pixel's split terms (add_split_terms; per column block: add_block_split_terms) and a pair's
// row held compactly (part_row_sum). The split lanes and the GEO record: split.h; the column blocks: raster.h.

#ifndef DC4GS_SPLIT_WALK_H
#define DC4GS_SPLIT_WALK_H

#include "raster.h"
#include "split.h"
#include "subgroups.h"

REQUIRE_DEFINED(SPLIT_CANDIDATES);
REQUIRE_DEFINED(SPLIT_SUMS_PER_BLOCK);

#if SPLIT_CANDIDATES
// The rectangle of pixels a crossing range covers (item-relative rows and columns from its first): with subgroups,
// the subgroup's (whole rows), so that its lanes walk alike and reduce the same candidates; else the work-item's
// pixels.
#if SUBGROUP
#define CROSS_ROWS (SUBGROUP / TILE_SIZE)
#define CROSS_COLS TILE_SIZE
#else
#define CROSS_ROWS ROWS_PER_ITEM
#define CROSS_COLS COLS_PER_ITEM
#endif

// The split candidates a pair's walk must test per pixel: (lo, hi), candidates lo .. hi - 1, in the rectangle holding
// the item's first pixel (tile row and column item_row0, item_col0; the rectangle's first: row0, col0). t(q) rounds
// monotonically in each pixel coordinate, so over the pixels the walk visits there (its rows within the span, its
// column blocks that meet the span) t lies within its values at the 4 corners: a candidate above them all has every
// walked pixel on its left (its left sums are the pair's totals), one at or below them none (zeros); only those in
// between, "crossing", are tested per pixel. A margin far above float rounding around t_k keeps pixels the walk might
// round across t_k tested: exact. The t_k increase with k (the candidates' order along the projected axis), so those
// with none left come first, those with all left last; were they out of order, every candidate counts as crossing.
// Large Gaussians span several tiles, each crossed by one or two candidates' lines. (Ternaries, not the integer min and
// max builtins, which PoCL calls rather than inlines: once per pair.)
ALWAYS_INLINE int2 crossing_range(const float4 line, const float *tk, const int4 span, const int x0, const int y0,
                                  const int item_row0, const int item_col0) {
    const int row0 = item_row0 / CROSS_ROWS * CROSS_ROWS, col0 = item_col0 / CROSS_COLS * CROSS_COLS;
    const int a = span.x - col0, b = span.y - col0;                   // the span, rectangle-relative
    const int r_lo = span.z > row0 ? span.z - row0 : 0;
    const int r_hi = span.w - row0 < CROSS_ROWS - 1 ? span.w - row0 : CROSS_ROWS - 1;
    if (b < 0 || a > CROSS_COLS - 1 || a > b || r_lo > r_hi)          // no pixel walked: none left of any
        return (int2)(SPLIT_CANDIDATES, SPLIT_CANDIDATES);
    const int c_lo = (a > 0 ? a : 0) / COL_BLOCK * COL_BLOCK;
    const int c_hi = (b < CROSS_COLS - 1 ? b : CROSS_COLS - 1) / COL_BLOCK * COL_BLOCK + COL_BLOCK - 1;
    float t_min = 0.f, t_max = 0.f, extent = 0.f;
    for (int corner = 0; corner < 4; ++corner) {
        // the pixel centres as the kernel sets px and py
        const float ex = ((float)(x0 + col0 + (corner & 1 ? c_hi : c_lo)) + 0.5f) - line.x;
        const float ey = ((float)(y0 + row0 + (corner & 2 ? r_hi : r_lo)) + 0.5f) - line.y;
        const float t = ex * line.z + ey * line.w;                    // as the walk computes t(q)
        t_min = corner ? MINF(t_min, t) : t;
        t_max = corner ? MAXF(t_max, t) : t;
        extent = MAXF(extent, ABSF(ex) + ABSF(ey));
    }
    const float margin = 1e-5f * (1.f + extent);
    int none_left = 0, all_left = 0, in_order = 1;
    for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
        const int none = t_min > tk[k] + margin, all = t_max < tk[k] - margin;
        in_order &= (!none | (none_left == k)) & (all | (all_left == 0));
        none_left += none;
        all_left += all;
    }
    return in_order ? (int2)(none_left, SPLIT_CANDIDATES - all_left) : (int2)(0, SPLIT_CANDIDATES);
}

// Sum k (< SUM_WIDTH) of a pair's row held compactly (row: its sums before SUM_SPLIT, then the split sums of the
// crossing candidates lo .. hi - 1 alone, crossing_range): a candidate below lo has none of the pixels on its left
// (zeros), one at or past hi all of them (the row's totals).
ALWAYS_INLINE float part_row_sum(__local const float *row, const int lo, const int hi, const int k) {
    if (k < SUM_SPLIT) return row[k];
    const int candidate = (k - SUM_SPLIT) / SPLIT_WIDTH, v = (k - SUM_SPLIT) % SPLIT_WIDTH;
    if (candidate < lo) return 0.f;
    if (candidate < hi) return row[SUM_SPLIT + SPLIT_WIDTH * (candidate - lo) + v];
    return row[SPLIT_TOTAL_AT(v)];
}

// A pair's candidate line (c0.x, c0.y, dir.x, dir.y) from its split-geometry row sg, and the candidates' positions
// along it, tk (t_0 = 0): pixel q is left of candidate k when t(q) = (q - c0) . dir < t_k; no split terms where
// the view gave no line (dir = 0).
ALWAYS_INLINE float4 candidate_line(__local const float *sg, float *tk) {
    tk[0] = 0.f;
    for (int k = 1; k < SPLIT_CANDIDATES; ++k) tk[k] = sg[GEO_T + k - 1];
    return (float4)(sg[GEO_ORIGIN], sg[GEO_ORIGIN + 1], sg[GEO_DIR], sg[GEO_DIR + 1]);
}

#if !SPLIT_SUMS_PER_BLOCK
// A pixel's split terms, in the walk: into its column lane c of split_lanes (SPLIT_WIDTH per candidate), for each of
// the n_split candidates at t_split[0 .. n_split - 1] that has the pixel (at t_q along the line) on its left: its split
// lanes' values where g != 0 (has_g). Fully unrolled: a loop here keeps the compiler from vectorising the pixel loop
// (11x slower). A literal trip count, unrolled before the call is inlined; the candidates past n_split then fold away.
ALWAYS_INLINE void add_split_terms(float split_lanes[][COL_BLOCK], const int c, const float *t_split,
                                   const int n_split, const float t_q, const float has_g, const float ux,
                                   const float uy, const float ax, const float ay) {
    #pragma unroll
    for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
        if (k >= n_split) break;
        float left = t_q < t_split[k] ? has_g : 0.f;
        split_lanes[SPLIT_WIDTH * k + SPLIT_UX][c] += left * ux;
        split_lanes[SPLIT_WIDTH * k + SPLIT_UY][c] += left * uy;
        split_lanes[SPLIT_WIDTH * k + SPLIT_COUNT][c] += left;
        split_lanes[SPLIT_WIDTH * k + SPLIT_ABS_X][c] += left * ax;
        split_lanes[SPLIT_WIDTH * k + SPLIT_ABS_Y][c] += left * ay;
    }
}
#else
// -D SPLIT_SUMS_PER_BLOCK=1 (Tuning.split_sums_per_block): the split terms of a column block's pixels, after their
// walk, in explicit vector adds (sv: the pixels' t along the line, then their split lanes' values where g != 0).
ALWAYS_INLINE void add_block_split_terms(float split_lanes[][COL_BLOCK], float sv[][COL_BLOCK], const float *t_split,
                                         const int n_split) {
    const floatB t_q = LOADB(sv[0]), zero = (floatB)(0.f);
    #pragma unroll
    for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
        if (k >= n_split) break;
        #pragma unroll
        for (int v = 0; v < SPLIT_WIDTH; ++v) {
            float *lane = split_lanes[SPLIT_WIDTH * k + v];
            STOREB(LOADB(lane) + (t_q < t_split[k] ? LOADB(sv[1 + v]) : zero), lane);
        }
    }
}
#endif
#endif

#endif
