// runs.h: work cut into contiguous runs of elements, the counts that size it, a work-group's exclusive sum.

#ifndef DC4GS_RUNS_H
#define DC4GS_RUNS_H

REQUIRE_DEFINED(HOST_COUNT);   // count_at for a count the host knows (constants.py): no count is read

// The elements to work on: `bound` (what the launch and the buffers are sized for) or, where count_at names a
// count the device wrote (count[count_at]: the visible Gaussians, the pairs), that count, never above the bound.
// The host then needs no read-back before it launches.
inline uint element_count(uint bound, __global const uint *count, uint count_at) {
    return count_at == HOST_COUNT ? bound : min(bound, count[count_at]);
}

// Elements per run when n elements are cut into `runs` runs of whole `multiple`s (the last run may hold fewer,
// the runs after it none).
inline uint run_length(uint n, uint runs, uint multiple) {
    uint len = (n + runs - 1u) / runs;
    return (len + multiple - 1u) / multiple * multiple;
}

// Exclusive sum of `mine` over the work-group's `size` items (Hillis-Steele on the inclusive sums, part[size] in
// local memory): returns this item's exclusive value and leaves the group's total in *total. Every item must
// call it; part may be reused once it returns (its last barrier).
inline uint group_exclusive_sum(__local uint *part, uint mine, uint size, uint *total) {
    uint lid = get_local_id(0);
    part[lid] = mine;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint off = 1; off < size; off <<= 1) {
        uint add = lid >= off ? part[lid - off] : 0u;
        barrier(CLK_LOCAL_MEM_FENCE);
        part[lid] += add;
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    *total = part[size - 1];
    uint exclusive = part[lid] - mine;
    barrier(CLK_LOCAL_MEM_FENCE);
    return exclusive;
}

#endif
