// isect.cl: from projected Gaussians to the per-tile, front-to-back lists the rasterizer walks.
//
// Two stable sorts replace one sort of 64-bit (tile | depth) keys: the visible Gaussians are sorted by
// depth once (V keys), their (tile, Gaussian) pairs are emitted in that order, and a stable sort by
// tile id alone (ceil(log2(tiles)) bits) leaves every tile's pairs front to back.
// Only Gaussians with pairs take part ("visible" below): culled ones emit no keys at all.
// The frame's counts live on the device, frame [FRAME_WORDS] uint (constants.py): V (the flag scan's total), the
// depth keys' range, P (the count scan's total), and whether P overflowed the pair capacity C the buffers were
// given. The kernels take V and P from there, launched for all N and for C, so the host reads nothing back first.
//   compact_visible:    tiles_touched [N], visible_offset [N] (exclusive scan of tiles_touched != 0), depth [N]
//                       -> visible_ids [V], depth_keys [V] (uint bits of the positive depth, which sort
//                       like the floats), frame: atomic min and max of the keys
//   (exclusive scan of tiles_touched [ids_by_depth [i]], i < V: pair_offset [V], P)
//   emit_pairs:         ids_by_depth [V], pair_offset [V], mean2d [N*2],
//                       radius [N], alpha_extent [N*2] -> per pair in emission order e < C: tile_of_emission [C],
//                       emission [C] (= e, the values the tile sort carries), gaussian_of_emission [C];
//                       per visible Gaussian g: pair_first [N], its first e (its pairs are e .. e + tiles - 1);
//                       frame's OVERFLOWED where P > C (the pairs from C on are not written)
//   (stable sort of (tile_of_emission, emission) by tile, of the first min(P, C))
//   gather_pairs:       emission_sorted [C], gaussian_of_emission [C] -> gaussian_of_pair [C] (the list the
//                       rasterizer walks), pair_of_emission [C] (where each emitted pair landed); and
//                       tile_of_pair [C] (sorted by tile) -> ranges [tiles*2] (first pair, end pair), the host
//                       zero-filling ranges first, so empty tiles stay (0, 0)

#include "tiles.h"

__kernel __attribute__((reqd_work_group_size(ISECT_WG, 1, 1)))
void compact_visible(const uint n, __global const uint *tiles_touched, __global const uint *visible_offset,
                     __global const float *depth, __global uint *visible_ids, __global uint *depth_keys,
                     __global uint *frame) {
    __local uint lo[ISECT_WG], hi[ISECT_WG];
    uint i = get_global_id(0), lid = get_local_id(0);
    uint kmin = 0xffffffffu, kmax = 0u;
    if (i < n && tiles_touched[i] > 0) {
        uint key = as_uint(depth[i]);
        uint at = visible_offset[i];
        visible_ids[at] = i;
        depth_keys[at] = key;
        kmin = kmax = key;
    }
    lo[lid] = kmin;
    hi[lid] = kmax;
    for (uint off = ISECT_WG / 2; off > 0; off >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lid < off) { lo[lid] = min(lo[lid], lo[lid + off]); hi[lid] = max(hi[lid], hi[lid + off]); }
    }
    if (lid == 0) {
        atomic_min(&frame[FRAME_DEPTH_KEY_MIN], lo[0]);
        atomic_max(&frame[FRAME_DEPTH_KEY_MAX], hi[0]);
    }
}

__kernel void emit_pairs(__global uint *frame, const uint capacity, const int tiles_x, const int tiles_y,
                         __global const uint *ids_by_depth,
                         __global const uint *pair_offset, __global const float *mean2d,
                         __global const int *radius, __global const float *alpha_extent,
                         __global uint *tile_of_emission, __global uint *emission,
                         __global uint *gaussian_of_emission, __global uint *pair_first) {
    uint i = get_global_id(0);
    if (i >= frame[FRAME_VISIBLE]) return;
    uint g = ids_by_depth[i];
    int4 rect = pair_rect(vload2(g, mean2d), (float)radius[g], vload2(g, alpha_extent), tiles_x, tiles_y);
    uint at = pair_offset[i];
    pair_first[g] = at;
    // the one Gaussian whose pairs reach past the capacity says so (P > C)
    if (at <= capacity && capacity < at + (uint)((rect.z - rect.x) * (rect.w - rect.y)))
        frame[FRAME_OVERFLOWED] = PAIRS_OVERFLOWED;
    for (int ty = rect.y; ty < rect.w; ++ty)
        for (int tx = rect.x; tx < rect.z && at < capacity; ++tx) {
            tile_of_emission[at] = (uint)(ty * tiles_x + tx);
            emission[at] = at;
            gaussian_of_emission[at] = g;
            ++at;
        }
}

__kernel void gather_pairs(__global const uint *frame, const uint capacity, __global const uint *emission_sorted,
                           __global const uint *gaussian_of_emission, __global const uint *tile_of_pair,
                           __global uint *gaussian_of_pair, __global uint *pair_of_emission, __global uint *ranges) {
    uint i = get_global_id(0), p = min(frame[FRAME_PAIRS], capacity);
    if (i >= p) return;
    uint e = emission_sorted[i];
    gaussian_of_pair[i] = gaussian_of_emission[e];
    pair_of_emission[e] = i;
    uint t = tile_of_pair[i];
    if (i == 0 || tile_of_pair[i - 1] != t) ranges[2 * t] = i;
    if (i == p - 1 || tile_of_pair[i + 1] != t) ranges[2 * t + 1] = i + 1;
}
