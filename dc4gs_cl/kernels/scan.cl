// scan.cl: exclusive prefix sum of uint (reduce, then scan), a reusable primitive.
//
// The n elements (runs.h element_count: `bound`, or a count the device wrote, count[count_at]) are cut into
// contiguous items of the same length, one per work-item of the launch, each walked in sequence
// (cache-friendly on CPUs); a work-group of SCAN_WG items forms a block.
//   scan_reduce: in [n] -> block_sums [groups]
//   scan_sums:   one work-item scans block_sums in place and stores the grand total in total[total_at]
//   scan_apply:  in [n] -> out [n] exclusive sums (out may alias in)
// -D SCAN_WG: work-group size (power of two). -D SCAN_FLAGS=1: scan (x != 0) instead of x (compaction).

#include "common.h"
#include "runs.h"

REQUIRE_DEFINED(SCAN_FLAGS);

#if SCAN_FLAGS
#define SCAN_VALUE(x) ((x) != 0u ? 1u : 0u)
#else
#define SCAN_VALUE(x) (x)
#endif

inline uint item_sum(uint n, uint item_len, __global const uint *in, uint start) {
    uint end = min(n, start + item_len), s = 0;
    for (uint i = start; i < end; ++i) s += SCAN_VALUE(in[i]);
    return s;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_reduce(const uint bound, __global const uint *count, const uint count_at, __global const uint *in,
                 __global uint *block_sums) {
    __local uint part[SCAN_WG];
    uint n = element_count(bound, count, count_at), item_len = run_length(n, get_global_size(0), 1u), total;
    group_exclusive_sum(part, item_sum(n, item_len, in, get_global_id(0) * item_len), SCAN_WG, &total);
    if (get_local_id(0) == 0) block_sums[get_group_id(0)] = total;
}

__kernel void scan_sums(const uint groups, __global uint *block_sums, __global uint *total, const uint total_at) {
    uint s = 0;
    for (uint g = 0; g < groups; ++g) { uint v = block_sums[g]; block_sums[g] = s; s += v; }
    total[total_at] = s;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_apply(const uint bound, __global const uint *count, const uint count_at, __global const uint *in,
                __global uint *out, __global const uint *block_sums) {
    __local uint part[SCAN_WG];
    uint n = element_count(bound, count, count_at), item_len = run_length(n, get_global_size(0), 1u), total;
    uint start = get_global_id(0) * item_len;
    uint s = block_sums[get_group_id(0)] + group_exclusive_sum(part, item_sum(n, item_len, in, start), SCAN_WG, &total);
    uint end = min(n, start + item_len);
    for (uint i = start; i < end; ++i) { uint v = SCAN_VALUE(in[i]); out[i] = s; s += v; }
}
