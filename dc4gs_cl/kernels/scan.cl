// scan.cl: exclusive prefix sum of uint (reduce, then scan), a reusable primitive.
//
// The input is cut into contiguous items of `item_len` elements; each work-item walks its item
// sequentially (cache-friendly on CPUs), a work-group of SCAN_WG items forms a block.
//   scan_reduce: in [n] -> block_sums [groups]
//   scan_sums:   one work-item scans block_sums in place and stores the grand total in total[total_at]
//   scan_apply:  in [n] -> out [n] exclusive sums (out may alias in)
// -D SCAN_WG: work-group size (power of two). -D SCAN_FLAGS=1: scan (x != 0) instead of x (compaction).

#include "common.h"

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

// Exclusive scan of part[SCAN_WG] in local memory (Hillis-Steele on the inclusive sums); returns this
// item's exclusive value and leaves the work-group total in *total.
inline uint work_group_exclusive(__local uint *part, uint mine, uint *total) {
    uint lid = get_local_id(0);
    part[lid] = mine;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint off = 1; off < SCAN_WG; off <<= 1) {
        uint add = lid >= off ? part[lid - off] : 0u;
        barrier(CLK_LOCAL_MEM_FENCE);
        part[lid] += add;
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    *total = part[SCAN_WG - 1];
    return part[lid] - mine;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_reduce(const uint n, const uint item_len, __global const uint *in, __global uint *block_sums) {
    __local uint part[SCAN_WG];
    uint total;
    work_group_exclusive(part, item_sum(n, item_len, in, get_global_id(0) * item_len), &total);
    if (get_local_id(0) == 0) block_sums[get_group_id(0)] = total;
}

__kernel void scan_sums(const uint groups, __global uint *block_sums, __global uint *total, const uint total_at) {
    uint s = 0;
    for (uint g = 0; g < groups; ++g) { uint v = block_sums[g]; block_sums[g] = s; s += v; }
    total[total_at] = s;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_apply(const uint n, const uint item_len, __global const uint *in, __global uint *out,
                __global const uint *block_sums) {
    __local uint part[SCAN_WG];
    uint start = get_global_id(0) * item_len, total;
    uint s = block_sums[get_group_id(0)] + work_group_exclusive(part, item_sum(n, item_len, in, start), &total);
    uint end = min(n, start + item_len);
    for (uint i = start; i < end; ++i) { uint v = SCAN_VALUE(in[i]); out[i] = s; s += v; }
}
