// sum_pairs.cl: the rasterizer backward's per-pair slots (rasterize_backward.cl, -D PAIR_SUMS=1) reduced to
// per-Gaussian sums (the SUM record: offsets SUM_<FIELD>, SUM_WIDTH, SPLIT_CANDIDATES and the GEO record's
// offsets are -D options from dc4gs_cl/statistics.py), in a fixed order: the deterministic design.

#include "common.h"
#include "split.h"

REQUIRE_DEFINED(FOLD_WINDOW);
#if FOLD_WINDOW
// window_fold.h requires SPLIT_CANDIDATES too
#include "window_fold.h"
#else
REQUIRE_DEFINED(SPLIT_CANDIDATES);
#endif

// acc += Gaussian g's slots of the pairs pair0 .. pair_end - 1, in emission order.
ALWAYS_INLINE void add_slots(const uint g, const uint pair0, const uint pair_end, __global const uint *tiles_touched,
                             __global const uint *pair_first, __global const uint *pair_of_emission,
                             __global const float *pair_sums, __global const float *split_geometry, float *acc) {
#if SPLIT_CANDIDATES
    __global const float *geo = split_geometry + (size_t)g * GEO_WIDTH;
    const int used = HAS_SPLIT_LINE(geo) ? SUM_WIDTH : SUM_SPLIT;
#else
    const int used = SUM_WIDTH;
#endif
    uint count = tiles_touched[g], first = count ? pair_first[g] : 0;
    for (uint e = first; e < first + count; ++e) {
        uint pair = pair_of_emission[e];
        if (pair < pair0 || pair >= pair_end) continue;
        __global const float *slot = pair_sums + (size_t)(pair - pair0) * SUM_WIDTH;
        for (int k = 0; k < used; ++k) acc[k] += slot[k];
    }
}

// Each Gaussian's slots of the pairs pair0 .. pair_end - 1 (run `run` of a view walked in runs of consecutive
// pairs, rasterize_backward.cl) added in emission order (the split sums only where it had a line: elsewhere the
// backward left them unwritten). A Gaussian's emissions go through its tiles in increasing tile id, so its pairs'
// indices increase too: the runs, summed one after another onto the sums, add in the same order as one run.
//   in  tiles_touched [N], pair_first [N], pair_of_emission [P]: from isect.cl;
//       pair_sums [(pair_end - pair0)*SUM_WIDTH]; split_geometry [N*GEO_WIDTH] with SPLIT_CANDIDATES;
//       spans [N] (in_runs = 1): each Gaussian's first and last run (run_spans); in_runs = 0: one run, run 0
//   out sums [N*SUM_WIDTH]: written in run 0 for every Gaussian, added to past it for those with a pair in the run
// -D FOLD_WINDOW=1: each Gaussian's sums are folded into the densification window here (window_fold.h; the
// window's arguments and -D options as densify_stats.cl's), and only the gradients reach memory: sums
// [N*GRADIENT_WIDTH], the SUM record's first GRADIENT_WIDTH fields. A Gaussian is folded in its last run (one
// with no pair, in run 0); one whose pairs span runs carries its partial sums from run to run in a carry row
// (SUM_WIDTH floats): carry_slot [N] names its row, taken in its first run (atomic_inc on carried [1], which the
// host zeroes for each view; carry holds at least as many rows as run_spans counted, or the frame is void). The
// rows are taken in any order; each Gaussian's sums still add its pairs in emission order, so a frame gives the
// same window and gradients, bit for bit, in one run or in many.
__kernel UNPACKED_WORK_ITEMS
void sum_pairs(__global const uint *frame, const uint n, const uint pair0, const uint pair_end, const uint run,
               const int in_runs, __global const uint *spans,
               __global const uint *tiles_touched, __global const uint *pair_first,
               __global const uint *pair_of_emission, __global const float *pair_sums,
               __global const float *split_geometry,
#if FOLD_WINDOW
               const float ndc_x, const float ndc_y, const float depth_scale, const float track_threshold,
               __global const int *radius, __global const float *depth, __global float *window,
               __global uint *carry_slot, __global uint *carried, __global float *carry,
#endif
               __global float *sums) {
    if (FRAME_VOID(frame)) return;   // every item: its pairs reach past the buffers, and the window stays
    const uint g = get_global_id(0);
    const uint span = g < n && in_runs ? spans[g] : 0u;        // first run << 16 | last run
    const uint first_run = span >> 16, last_run = span & 0xFFFFu;
    const int in_run = g < n && first_run <= run && run <= last_run;
    float acc[SUM_WIDTH];
#if FOLD_WINDOW
    const int starts = first_run == run, ends = last_run == run;
    uint row = 0;
    if (in_run && !starts) row = carry_slot[g];
    for (int k = 0; k < SUM_WIDTH; ++k) acc[k] = in_run && !starts ? carry[(size_t)row * SUM_WIDTH + k] : 0.f;
    if (in_run)
        add_slots(g, pair0, pair_end, tiles_touched, pair_first, pair_of_emission, pair_sums, split_geometry, acc);
    // The fold comes past a barrier, which makes it PoCL's own loop over the work-items: that vectorises, as
    // densify_stats does, where after the slots' loop of varying length it ran one Gaussian at a time (4.3 ms
    // against 1.6 + 1.0 for sum_pairs and densify_stats, 48k Gaussians, DC4GS). It then runs, masked, for every
    // work-item of a run's launch: the host folds here only in a few runs (Tuning.max_folded_runs).
    barrier(CLK_LOCAL_MEM_FENCE);
    if (!in_run) return;
    if (!ends) {                                  // more of its pairs in later runs: carry the partial sums
        if (starts) carry_slot[g] = row = atomic_inc(carried);
        for (int k = 0; k < SUM_WIDTH; ++k) carry[(size_t)row * SUM_WIDTH + k] = acc[k];
        return;
    }
    fold_view_sums(g, acc, ndc_x, ndc_y, depth_scale, track_threshold, radius, depth, split_geometry, window);
    for (int k = 0; k < GRADIENT_WIDTH; ++k) sums[(size_t)g * GRADIENT_WIDTH + k] = acc[k];
#else
    // Past the first run, a Gaussian with no pair in this one keeps its sums untouched (most of them).
    if (g >= n || (run && !in_run)) return;
    for (int k = 0; k < SUM_WIDTH; ++k) acc[k] = run ? sums[(size_t)g * SUM_WIDTH + k] : 0.f;
    if (in_run)
        add_slots(g, pair0, pair_end, tiles_touched, pair_first, pair_of_emission, pair_sums, split_geometry, acc);
    for (int k = 0; k < SUM_WIDTH; ++k) sums[(size_t)g * SUM_WIDTH + k] = acc[k];
#endif
}

// Each Gaussian's runs (a view walked in runs of pairs_per_run consecutive pairs, run r holding the pairs
// r * pairs_per_run ..): spans [n], the run of its first pair in the high 16 bits and of its last in the low 16
// (0, 0 for one with no pair: run 0 writes its zero sums and folds it), and the Gaussians whose pairs lie in more
// than one run (each takes a carry row in sum_pairs with a window) added onto frame [FRAME_SPANNING]; past
// carry_rows of them the frame is void (FRAME_OVERFLOWED; the trainer runs the view again with more rows). This
// runs before anything that changes lasting state is queued (the loss' sums included). A work-group counts its
// own first, so the frame's counter takes one atomic per group.
__kernel void run_spans(__global uint *frame, const uint n, const uint pairs_per_run, const uint carry_rows,
                        __global const uint *tiles_touched, __global const uint *pair_first,
                        __global const uint *pair_of_emission, __global uint *spans) {
    // Nothing where the pairs reach past the buffers (none spans, then); every group counts its own where another
    // group of this launch found too few carry rows. (No return before the barriers: PoCL then counts each group
    // once per item.)
    const int pairs_void = (frame[FRAME_OVERFLOWED] & PAIRS_OVERFLOWED) != 0u;
    __local uint group_spanning;
    const uint g = get_global_id(0);
    if (get_local_id(0) == 0) group_spanning = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint count = g < n && !pairs_void ? tiles_touched[g] : 0;
    if (g < n && !pairs_void) {
        uint span = 0;
        if (count) {
            const uint first = pair_of_emission[pair_first[g]] / pairs_per_run;
            const uint last = pair_of_emission[pair_first[g] + count - 1] / pairs_per_run;
            span = first << 16 | last;
            if (first != last) atomic_inc(&group_spanning);
        }
        spans[g] = span;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0 && group_spanning) {
        const uint before = atomic_add(&frame[FRAME_SPANNING], group_spanning);
        if (before + group_spanning > carry_rows) atomic_or(&frame[FRAME_OVERFLOWED], CARRY_OVERFLOWED);
    }
}
