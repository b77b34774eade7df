// sort.cl: stable LSD radix sort of uint keys carrying uint values, a reusable primitive.
//
// One pass sorts by the digit (key >> shift) & digit_mask, digit_mask = 2^bits - 1 with bits <= RADIX_BITS, in
// three launches (reduce, then scan, then scatter). The n keys (runs.h element_count: `bound`, or the count the
// device wrote at count[count_at]) are cut into `blocks` contiguous runs (runs.h run_length), one per work-item
// or work-group of the launch:
//   radix_histogram: keys [n] -> hist [RADIX][blocks] (digit-major), counts of each digit per run
//   radix_spine:     hist, in place: its exclusive sum, flattened (the start of each (digit, run) in the output)
//   radix_scatter:   keys_in, vals_in [n] -> keys_out, vals_out [n]
// The host names the bits to sort: only the tile-id bits a frame uses; all 31 bits a depth key can have.
//
// Two shapes, the same output (a stable sort is unique):
//   -D SORT_WG=1 (CPUs): a run per work-item, walked in sequence, which keeps every pass stable with no ranking
//     and each core streaming through memory; the spine is one work-item.
//   -D SORT_WG>1 (GPUs): a run per work-group of SORT_WG items, walked in tiles of TILE_KEYS keys loaded
//     coalesced; each tile is sorted stably in local memory by its digit, LOCAL_BITS bits at a time (a split
//     per LOCAL_BITS: every item counts its KEYS_PER_ITEM consecutive keys into its own column, one group scan
//     of the columns, digit-major, ranks them, so no atomics and no subgroup operation), then written out in
//     runs of equal digits, consecutive items to consecutive addresses. 8-bit digits thus need no ballot.
// -D RADIX_BITS: the widest digit. -D KEYS_PER_ITEM (SORT_WG > 1).

#include "common.h"
#include "runs.h"

REQUIRE_DEFINED(RADIX_BITS);
REQUIRE_DEFINED(SORT_WG);

#define RADIX (1u << RADIX_BITS)
#define DIGIT(key) (((key) >> shift) & digit_mask)

#if SORT_WG == 1

__kernel void radix_histogram(const uint bound, __global const uint *count, const uint count_at, const uint shift,
                              const uint digit_mask, __global const uint *keys, __global uint *hist) {
    uint b = get_global_id(0), blocks = get_global_size(0);
    uint n = element_count(bound, count, count_at), block_len = run_length(n, blocks, 1u);
    uint digits[RADIX];
    for (uint d = 0; d < RADIX; ++d) digits[d] = 0;
    uint end = min(n, (b + 1) * block_len);
    for (uint i = b * block_len; i < end; ++i) digits[DIGIT(keys[i])]++;
    for (uint d = 0; d < RADIX; ++d) hist[d * blocks + b] = digits[d];
}

__kernel void radix_scatter(const uint bound, __global const uint *count, const uint count_at, const uint shift,
                            const uint digit_mask, __global const uint *keys_in, __global const uint *vals_in,
                            __global const uint *hist_scanned, __global uint *keys_out, __global uint *vals_out) {
    uint b = get_global_id(0), blocks = get_global_size(0);
    uint n = element_count(bound, count, count_at), block_len = run_length(n, blocks, 1u);
    uint next[RADIX];
    for (uint d = 0; d < RADIX; ++d) next[d] = hist_scanned[d * blocks + b];
    uint end = min(n, (b + 1) * block_len);
    for (uint i = b * block_len; i < end; ++i) {
        uint k = keys_in[i];
        uint dst = next[DIGIT(k)]++;
        keys_out[dst] = k;
        vals_out[dst] = vals_in[i];
    }
}

#else

REQUIRE_DEFINED(KEYS_PER_ITEM);
#define TILE_KEYS (SORT_WG * KEYS_PER_ITEM)
#define LOCAL_BITS 4
#define LOCAL_RADIX (1u << LOCAL_BITS)
typedef char tile_positions_fit_16_bits[TILE_KEYS <= 65535 ? 1 : -1];

// Each work-group counts its run's digits in local memory (integer adds: the counts do not depend on their order).
__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_histogram(const uint bound, __global const uint *count, const uint count_at, const uint shift,
                     const uint digit_mask, __global const uint *keys, __global uint *hist) {
    __local uint l_count[RADIX];
    uint lid = get_local_id(0), b = get_group_id(0), blocks = get_num_groups(0);
    uint n = element_count(bound, count, count_at), block_len = run_length(n, blocks, TILE_KEYS);
    for (uint d = lid; d < RADIX; d += SORT_WG) l_count[d] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    uint end = min(n, (b + 1) * block_len);
    for (uint i = b * block_len + lid; i < end; i += SORT_WG) atomic_inc(&l_count[DIGIT(keys[i])]);
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint d = lid; d < RADIX; d += SORT_WG) hist[d * blocks + b] = l_count[d];
}

// keys[TILE_KEYS], vals[TILE_KEYS] -> sorted[...] stably by the digit's bits [low, low + LOCAL_BITS);
// column[LOCAL_RADIX * SORT_WG]: per (local digit, item) counts, then their exclusive sums (below TILE_KEYS,
// so 16 bits: 28 KB of local memory in all at 256 items).
inline void split_tile(uint shift, uint digit_mask, uint low, __local const uint *keys, __local const uint *vals,
                       __local uint *sorted_keys, __local uint *sorted_vals, __local ushort *column,
                       __local uint *part) {
    uint lid = get_local_id(0), first = lid * KEYS_PER_ITEM;
#define LOCAL_DIGIT(key) ((DIGIT(key) >> low) & (LOCAL_RADIX - 1u))
    for (uint d = 0; d < LOCAL_RADIX; ++d) column[d * SORT_WG + lid] = 0;
    for (uint k = 0; k < KEYS_PER_ITEM; ++k) column[LOCAL_DIGIT(keys[first + k]) * SORT_WG + lid]++;
    barrier(CLK_LOCAL_MEM_FENCE);
    // The exclusive sum of the columns, digit-major: item i sums entries [i * LOCAL_RADIX, (i + 1) * LOCAL_RADIX)
    uint mine[LOCAL_RADIX], run = 0, total;
    for (uint j = 0; j < LOCAL_RADIX; ++j) { mine[j] = column[lid * LOCAL_RADIX + j]; run += mine[j]; }
    run = group_exclusive_sum(part, run, SORT_WG, &total);
    for (uint j = 0; j < LOCAL_RADIX; ++j) { column[lid * LOCAL_RADIX + j] = (ushort)run; run += mine[j]; }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint k = 0; k < KEYS_PER_ITEM; ++k) {   // each item moves its own keys, counting in its own column
        uint key = keys[first + k], dst = column[LOCAL_DIGIT(key) * SORT_WG + lid]++;
        sorted_keys[dst] = key;
        sorted_vals[dst] = vals[first + k];
    }
    barrier(CLK_LOCAL_MEM_FENCE);
#undef LOCAL_DIGIT
}

__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_scatter(const uint bound, __global const uint *count, const uint count_at, const uint shift,
                   const uint digit_mask, __global const uint *keys_in, __global const uint *vals_in,
                   __global const uint *hist_scanned, __global uint *keys_out, __global uint *vals_out) {
    __local uint l_keys[2][TILE_KEYS], l_vals[2][TILE_KEYS];
    __local ushort l_column[LOCAL_RADIX * SORT_WG];
    __local uint l_part[SORT_WG];
    __local uint l_next[RADIX], l_first[RADIX], l_end[RADIX];   // per digit: output position; the tile's range
    uint lid = get_local_id(0), b = get_group_id(0), blocks = get_num_groups(0);
    uint n = element_count(bound, count, count_at), block_len = run_length(n, blocks, TILE_KEYS);
    uint bits = popcount(digit_mask);
    for (uint d = lid; d < RADIX; d += SORT_WG) l_next[d] = hist_scanned[d * blocks + b];
    uint end = min(n, (b + 1) * block_len);
    for (uint t0 = b * block_len; t0 < end; t0 += TILE_KEYS) {
        uint valid = min((uint)TILE_KEYS, end - t0);
        // Keys past the run take the largest digit: they sort after every key of the tile, and are not written.
        for (uint k = 0; k < KEYS_PER_ITEM; ++k) {
            uint j = k * SORT_WG + lid;
            l_keys[0][j] = j < valid ? keys_in[t0 + j] : 0xFFFFFFFFu;
            l_vals[0][j] = j < valid ? vals_in[t0 + j] : 0u;
        }
        for (uint d = lid; d < RADIX; d += SORT_WG) l_first[d] = l_end[d] = 0;
        barrier(CLK_LOCAL_MEM_FENCE);
        uint s = 0;
        for (uint low = 0; low < bits; low += LOCAL_BITS, s ^= 1)
            split_tile(shift, digit_mask, low, l_keys[s], l_vals[s], l_keys[s ^ 1], l_vals[s ^ 1], l_column, l_part);
        for (uint k = 0; k < KEYS_PER_ITEM; ++k) {   // where each digit's keys start and end in the sorted tile
            uint j = k * SORT_WG + lid, d = DIGIT(l_keys[s][j]);
            if (j == 0 || DIGIT(l_keys[s][j - 1]) != d) l_first[d] = j;
            if (j == TILE_KEYS - 1 || DIGIT(l_keys[s][j + 1]) != d) l_end[d] = j + 1;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (uint k = 0; k < KEYS_PER_ITEM; ++k) {
            uint j = k * SORT_WG + lid;
            if (j < valid) {
                uint key = l_keys[s][j], d = DIGIT(key), dst = l_next[d] + j - l_first[d];
                keys_out[dst] = key;
                vals_out[dst] = l_vals[s][j];
            }
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (uint d = lid; d < RADIX; d += SORT_WG) l_next[d] += l_end[d] - l_first[d];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
}

#endif

// One work-group: the exclusive sum of hist[len] in place, in tiles of SORT_WG * SPINE_PER_ITEM entries (each
// item sums its consecutive entries, one group scan per tile).
#define SPINE_PER_ITEM 16
__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_spine(const uint len, __global uint *hist) {
    __local uint part[SORT_WG];
    uint lid = get_local_id(0), carry = 0, total;
    for (uint t0 = 0; t0 < len; t0 += SORT_WG * SPINE_PER_ITEM) {
        uint first = t0 + lid * SPINE_PER_ITEM, mine[SPINE_PER_ITEM], run = 0;
        for (uint j = 0; j < SPINE_PER_ITEM; ++j) {
            mine[j] = first + j < len ? hist[first + j] : 0u;
            run += mine[j];
        }
        run = carry + group_exclusive_sum(part, run, SORT_WG, &total);
        for (uint j = 0; j < SPINE_PER_ITEM; ++j) {
            if (first + j < len) hist[first + j] = run;
            run += mine[j];
        }
        carry += total;
    }
}
