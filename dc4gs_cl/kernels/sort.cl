// sort.cl: stable LSD radix sort of uint keys carrying uint values, a reusable primitive.
//
// One pass sorts by the digit (key >> shift) & (2^digit_bits - 1), digit_bits <= RADIX_BITS. The keys
// are cut into `blocks` contiguous runs of `block_len`; each work-item owns one run and walks it
// sequentially, which keeps every pass stable without any ranking inside a work-group:
//   radix_histogram: keys [n] -> hist [RADIX][blocks] (digit-major), counts of each digit per run
//   (exclusive scan of hist, flattened, with scan.cl: the start of each (digit, run) in the output)
//   radix_scatter:   keys_in, vals_in [n] -> keys_out, vals_out [n]
// The host sorts only the bits that can differ, so a pass is never spent on constant bits.
// -D RADIX_BITS: the widest digit (counters per work-item: 2^RADIX_BITS).

#include "common.h"

#define RADIX (1u << RADIX_BITS)

__kernel void radix_histogram(const uint n, const uint block_len, const uint shift, const uint digit_mask,
                              __global const uint *keys, __global uint *hist) {
    uint b = get_global_id(0), blocks = get_global_size(0);
    uint count[RADIX];
    for (uint d = 0; d < RADIX; ++d) count[d] = 0;
    uint end = min(n, (b + 1) * block_len);
    for (uint i = b * block_len; i < end; ++i) count[(keys[i] >> shift) & digit_mask]++;
    for (uint d = 0; d < RADIX; ++d) hist[d * blocks + b] = count[d];
}

__kernel void radix_scatter(const uint n, const uint block_len, const uint shift, const uint digit_mask,
                            __global const uint *keys_in, __global const uint *vals_in,
                            __global const uint *hist_scanned,
                            __global uint *keys_out, __global uint *vals_out) {
    uint b = get_global_id(0), blocks = get_global_size(0);
    uint next[RADIX];
    for (uint d = 0; d < RADIX; ++d) next[d] = hist_scanned[d * blocks + b];
    uint end = min(n, (b + 1) * block_len);
    for (uint i = b * block_len; i < end; ++i) {
        uint k = keys_in[i];
        uint dst = next[(k >> shift) & digit_mask]++;
        keys_out[dst] = k;
        vals_out[dst] = vals_in[i];
    }
}
