// sum_pairs.cl: the rasterizer backward's per-pair slots (rasterize_backward.cl, -D PAIR_SUMS=1) reduced to
// per-Gaussian sums (the SUM record: offsets SUM_<FIELD>, SUM_WIDTH, SPLIT_CANDIDATES and the GEO record's
// offsets are -D options from dc4gs_cl/statistics.py), in a fixed order: the deterministic design.

#include "common.h"

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

// Each Gaussian's slots of the pairs pair0 .. pair_end - 1 (one run of tiles) added in emission order (the split
// sums only where it had a line: elsewhere the backward left them unwritten). A Gaussian's emissions go through
// its tiles in increasing tile id, so its pairs' indices increase too: the runs, summed one after another onto
// the sums (accumulate = 1 past the first), add in the same order as one run.
//   in  tiles_touched [N], pair_first [N], pair_of_emission [P]: from isect.cl;
//       pair_sums [(pair_end - pair0)*SUM_WIDTH]; split_geometry [N*GEO_WIDTH] with SPLIT_CANDIDATES
//   out sums [N*SUM_WIDTH] (in and out with accumulate)
// listed = 1: the work covers only the Gaussians with a pair in this run (run past the first), work-item i taking
// members [i] for i < listed_count [0] (run_members; the launch is sized for all n, so that the host reads no count
// back); otherwise work-item g takes Gaussian g of all n.
// -D FOLD_WINDOW=1: each Gaussian's sums are folded into the densification window here (window_fold.h; the
// window's arguments and -D options as densify_stats.cl's), and only the gradients reach memory: sums
// [N*GRADIENT_WIDTH], the SUM record's first GRADIENT_WIDTH fields. A Gaussian is folded in the run holding its
// last pair (one with no pair, in the first run); one whose pairs span runs carries its partial sums from run to
// run in a carry row (SUM_WIDTH floats): carry_slot [N] names its row, taken in the run holding its first pair
// (atomic_inc on carried [1], which the host zeroes for each view; carry holds as many rows as run_spans
// counted). The rows are taken in any order; each Gaussian's sums still add its pairs in emission order, so a
// frame gives the same window and gradients, bit for bit, in one run or in many (accumulate unused).
__kernel UNPACKED_WORK_ITEMS
void sum_pairs(__global const uint *frame, const uint n, const uint pair0, const uint pair_end, const int accumulate,
               const int listed, __global const uint *listed_count, __global const uint *members,
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
    const uint item = get_global_id(0);
    const uint g = !listed ? item : item < listed_count[0] ? members[item] : n;     // n: no Gaussian
    float acc[SUM_WIDTH];
#if FOLD_WINDOW
    // Where this run holds the Gaussian's first and last pair (pairs increase with emissions); a frame walked in
    // one run starts and ends every Gaussian in it.
    uint count = 0, first_pair = 0, last_pair = 0;
    if (g < n) count = tiles_touched[g];
    if (count) {
        first_pair = pair_of_emission[pair_first[g]];
        last_pair = pair_of_emission[pair_first[g] + count - 1];
    }
    const int in_run = count && first_pair < pair_end && last_pair >= pair0;
    const int starts = count ? in_run && first_pair >= pair0 : pair0 == 0;
    const int ends = count ? in_run && last_pair < pair_end : pair0 == 0;
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
    if (g >= n) return;
    if (!ends) {                                  // more of its pairs in later runs: carry the partial sums
        if (!in_run) return;
        if (starts) carry_slot[g] = row = atomic_inc(carried);
        for (int k = 0; k < SUM_WIDTH; ++k) carry[(size_t)row * SUM_WIDTH + k] = acc[k];
        return;
    }
    fold_view_sums(g, acc, ndc_x, ndc_y, depth_scale, track_threshold, radius, depth, split_geometry, window);
    for (int k = 0; k < GRADIENT_WIDTH; ++k) sums[(size_t)g * GRADIENT_WIDTH + k] = acc[k];
#else
    if (g >= n) return;
    uint count = tiles_touched[g], first = count ? pair_first[g] : 0;
    // Past the first run, a Gaussian with no pair in this one keeps its sums untouched (most of them).
    if (accumulate && (count == 0 || pair_of_emission[first + count - 1] < pair0
                       || pair_of_emission[first] >= pair_end))
        return;
    for (int k = 0; k < SUM_WIDTH; ++k) acc[k] = accumulate ? sums[(size_t)g * SUM_WIDTH + k] : 0.f;
    add_slots(g, pair0, pair_end, tiles_touched, pair_first, pair_of_emission, pair_sums, split_geometry, acc);
    for (int k = 0; k < SUM_WIDTH; ++k) sums[(size_t)g * SUM_WIDTH + k] = acc[k];
#endif
}

// Each Gaussian's runs of tiles (a view walked in runs): spans [n], the first run holding one of its pairs in the
// high 16 bits and the last in the low 16 (RUN_SPAN_NONE for a Gaussian with no pair), and the Gaussians whose pairs
// lie in more than one run (the carry rows sum_pairs takes with a window) added onto spanning [1] (the host zeroes
// it). run_ends [runs]: each run's end pair, increasing. A work-group counts its own first, so the global counter
// takes one atomic per group.
#define RUN_SPAN_NONE 0xFFFF0000u

// The run holding pair q: the first whose end lies past q.
inline uint run_of_pair(const uint q, const uint runs, __global const uint *run_ends) {
    uint lo = 0, hi = runs - 1;
    while (lo < hi) {
        const uint mid = (lo + hi) / 2;
        if (q < run_ends[mid]) hi = mid; else lo = mid + 1;
    }
    return lo;
}

__kernel void run_spans(__global const uint *frame, const uint n, const uint runs, __global const uint *run_ends,
                        __global const uint *tiles_touched, __global const uint *pair_first,
                        __global const uint *pair_of_emission, __global uint *spans, __global uint *spanning) {
    if (FRAME_VOID(frame)) return;   // every item: its pairs reach past the buffers (none spans, then)
    __local uint group_spanning;
    const uint g = get_global_id(0);
    if (get_local_id(0) == 0) group_spanning = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint count = g < n ? tiles_touched[g] : 0;
    if (g < n) {
        uint span = RUN_SPAN_NONE;
        if (count) {
            const uint first = run_of_pair(pair_of_emission[pair_first[g]], runs, run_ends);
            const uint last = run_of_pair(pair_of_emission[pair_first[g] + count - 1], runs, run_ends);
            span = first << 16 | last;
            if (first != last) atomic_inc(&group_spanning);
        }
        spans[g] = span;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0 && group_spanning) atomic_add(spanning, group_spanning);
}

// The Gaussians with a pair in run `run` (from run_spans), listed in members [count [0]] (the host zeroes the count):
// a work-group lists its own in one block, taken with one atomic on count.
__kernel void run_members(__global const uint *frame, const uint n, const uint run, __global const uint *spans,
                          __global uint *members, __global uint *count) {
    if (FRAME_VOID(frame)) return;   // every item: no spans were written (none is a member, then)
    __local uint group_count, group_base;
    const uint g = get_global_id(0);
    if (get_local_id(0) == 0) group_count = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint span = g < n ? spans[g] : RUN_SPAN_NONE;
    const int member = (span >> 16) <= run && run <= (span & 0xFFFFu);
    const uint slot = member ? atomic_inc(&group_count) : 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0) group_base = group_count ? atomic_add(count, group_count) : 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (member) members[group_base + slot] = g;
}
