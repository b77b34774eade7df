// scan.cl: exclusive prefix sum of uint (reduce, then scan), a reusable primitive.
//
// The n elements (runs.h element_count: `bound`, or a count the device wrote, count[count_at]) are cut into
// contiguous items of the same length, one per work-item of the launch, each walked in sequence
// (cache-friendly on CPUs); a work-group of SCAN_WG items forms a block.
//   scan_reduce: in [n] -> block_sums [groups], each block's sum
//   scan_apply:  in [n] -> out [n] exclusive sums (out may alias in); each work-group adds up the block sums
//                before its own (at most a few hundred: no launch of their own), the last stores the grand total
//                in total[total_at]
// -D SCAN_WG: work-group size (power of two). -D SCAN_FLAGS=1: scan (x != 0) instead of x (compaction).
// -D SCAN_GATHER=1: element i is in[order[i]] (order [n]: the intersection's visible Gaussians by depth), where
// a gather of its own would be a launch more.

#include "common.h"
#include "runs.h"

REQUIRE_DEFINED(SCAN_FLAGS);
REQUIRE_DEFINED(SCAN_GATHER);

#if SCAN_FLAGS
#define SCAN_VALUE(x) ((x) != 0u ? 1u : 0u)
#else
#define SCAN_VALUE(x) (x)
#endif

#if SCAN_GATHER
#define SCAN_ORDER , __global const uint *order
#define ELEMENT(in, i) SCAN_VALUE((in)[order[i]])
#define ORDER_ARG , order
#else
#define SCAN_ORDER
#define ELEMENT(in, i) SCAN_VALUE((in)[i])
#define ORDER_ARG
#endif

inline uint item_sum(uint n, uint item_len, __global const uint *in, uint start SCAN_ORDER) {
    uint end = min(n, start + item_len), s = 0;
    for (uint i = start; i < end; ++i) s += ELEMENT(in, i);
    return s;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_reduce(const uint bound, __global const uint *count, const uint count_at, __global const uint *in,
                 __global uint *block_sums SCAN_ORDER) {
    __local uint part[SCAN_WG];
    uint n = element_count(bound, count, count_at), item_len = run_length(n, get_global_size(0), 1u), total;
    group_exclusive_sum(part, item_sum(n, item_len, in, get_global_id(0) * item_len ORDER_ARG), SCAN_WG, &total);
    if (get_local_id(0) == 0) block_sums[get_group_id(0)] = total;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_apply(const uint bound, __global const uint *count, const uint count_at, __global const uint *in,
                __global uint *out, __global const uint *block_sums, __global uint *total, const uint total_at
                SCAN_ORDER) {
    __local uint part[SCAN_WG];
    uint n = element_count(bound, count, count_at), item_len = run_length(n, get_global_size(0), 1u), sum;
    const uint group = get_group_id(0);
    uint mine = 0, before;                           // the blocks before this group's, split over its items
    for (uint b = get_local_id(0); b < group; b += SCAN_WG) mine += block_sums[b];
    group_exclusive_sum(part, mine, SCAN_WG, &before);
    if (group == get_num_groups(0) - 1 && get_local_id(0) == 0) total[total_at] = before + block_sums[group];
    uint start = get_global_id(0) * item_len;
    uint s = before + group_exclusive_sum(part, item_sum(n, item_len, in, start ORDER_ARG), SCAN_WG, &sum);
    uint end = min(n, start + item_len);
    for (uint i = start; i < end; ++i) { uint v = ELEMENT(in, i); out[i] = s; s += v; }
}
