// exposure.cl: train --exposure, a 3x4 affine colour correction per training photo (the Inria code's 2024
// exposure), applied to the rendered image before the loss, its gradient summed over the image in a fixed order.
//
// corrections [N][12] float32 (unitless): photo v's T = [A | b] row-major, T[4i + j] = A_ij (j < 3),
// T[4i + 3] = b_i; a pixel's corrected colour out_i = sum_j A_ij rgb_j + b_i (rgb in [0, 1], not clamped).
// m, v [N][12]: Adam's moments of the corrections, in the colour coordinates (coords, below). Images [P][3]
// float32, interleaved RGB (P = H * W pixels).
//
//   exposure_apply     x [P][3], photo `view`'s T -> out [P][3] = A x + b
//   exposure_backward  g [P][3] (dL/dout, from the loss) in place -> dL/dx = A^T g (0 at masked pixels);
//                      dL/dT over each work-group's pixels (each item a contiguous run of PER_ITEM pixels, then a
//                      tree over the group's items) -> partial [groups][12]
//   exposure_step      one work-item: the partials added in group order -> grad_t [12]; then (a stepping
//                      iteration) Adam on every photo's T (one dense Adam over [N][12], as the Inria code's: a
//                      photo not seen moves by its momentum), taken in the photos' colour coordinates, and the
//                      anchor: the mean of T over the photos minus the identity subtracted from each, so that the
//                      mean correction stays the identity. A kernel of its own, not the last group of
//                      exposure_backward: OpenCL 1.2 makes no group's writes visible to another within a launch.
//                      The sums' order is fixed by the shape and the image alone: runs are bit-reproducible.
// coords [12] float32: the photos' colour coordinates, W [3][3] row-major then mu [3] (backward/exposure.py
// colour_coordinates: mu the photos' mean colour, W their colours' whitening, which only shrinks: the directions
// they vary along most, their brightness, scaled down to the mean variance). Adam steps a correction as
// P = [A W^-1 | b + A mu], i.e. out = P_A (W (x - mu)) + P_b, with m and v in these coordinates: the gain and the
// offset, and the three channels, which an image's colours make nearly collinear for T itself, are decorrelated
// there, so Adam's per-parameter steps move a correction straight toward its photo's (W = I, mu = 0: Adam on T).
// keep [P] uchar, read where masked != 0 (0: the pixel is masked out): masked pixels add nothing. A void frame (FRAME_VOID) changes
// nothing: the view runs again. Work shape: WG items a group (a power of two), PER_ITEM pixels an item.

#include "adam.h"

#define PARAMS 12   // a correction's floats

ALWAYS_INLINE void affine(__global const float *T, float r, float g, float b, float out[3]) {
    for (int i = 0; i < 3; ++i)
        out[i] = T[4 * i] * r + T[4 * i + 1] * g + T[4 * i + 2] * b + T[4 * i + 3];
}

__kernel void exposure_apply(const int pixels, const int view, __global const float *restrict corrections,
                             __global const float *restrict x, __global float *restrict out) {
    const int p = get_global_id(0);
    if (p >= pixels) return;
    float y[3];
    affine(corrections + PARAMS * view, x[3 * p], x[3 * p + 1], x[3 * p + 2], y);
    for (int i = 0; i < 3; ++i) out[3 * p + i] = y[i];
}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void exposure_backward(const int pixels, const int view, __global const float *restrict corrections,
                       __global const float *restrict x, __global float *restrict g,
                       const int masked, __global const uchar *restrict keep, __global const uint *frame,
                       __global float *restrict partial) {
    __local float red[PARAMS * WG];
    if (FRAME_VOID(frame)) return;   // every item: nothing changes
    const int lid = get_local_id(0), group = get_group_id(0);
    __global const float *T = corrections + PARAMS * view;
    float s[PARAMS];
    for (int q = 0; q < PARAMS; ++q) s[q] = 0.0f;
    const int p0 = get_global_id(0) * PER_ITEM, p1 = min(p0 + PER_ITEM, pixels);
    for (int p = p0; p < p1; ++p) {
        const int kept = !masked || keep[p];
        float gi[3], xj[3] = {x[3 * p], x[3 * p + 1], x[3 * p + 2]};
        for (int i = 0; i < 3; ++i) gi[i] = kept ? g[3 * p + i] : 0.0f;   // a select: masked g may be anything
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) s[4 * i + j] += gi[i] * xj[j];
            s[4 * i + 3] += gi[i];
        }
        for (int j = 0; j < 3; ++j) g[3 * p + j] = T[j] * gi[0] + T[4 + j] * gi[1] + T[8 + j] * gi[2];
    }
    // the group's sum: a tree over its items, in the same order every run
    for (int q = 0; q < PARAMS; ++q) red[q * WG + lid] = s[q];
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int stride = WG / 2; stride > 0; stride >>= 1) {
        if (lid < stride)
            for (int q = 0; q < PARAMS; ++q) red[q * WG + lid] += red[q * WG + lid + stride];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (lid == 0)
        for (int q = 0; q < PARAMS; ++q) partial[PARAMS * group + q] = red[q * WG];
}

__kernel void exposure_step(const int groups, const int view, const int photos, __global float *restrict corrections,
                            __global float *restrict m, __global float *restrict v, const AdamStep step,
                            __global const float *restrict coords, __global const uint *frame,
                            __global const float *restrict partial, __global float *restrict grad_t) {
    if (FRAME_VOID(frame)) return;   // the view runs again: nothing changes
    float total[PARAMS];
    for (int q = 0; q < PARAMS; ++q) {   // the partials in group order
        float t = 0.0f;
        for (int k = 0; k < groups; ++k) t += partial[PARAMS * k + q];
        total[q] = grad_t[q] = t;
    }
    if (!(step.stepping & 1u)) return;   // no optimiser step this iteration: the gradient alone
    // Adam on every photo's T in the photos' colour coordinates (see the top): photo `view`'s gradient there,
    // dL/dP_A = (dL/dA - dL/db mu^T) W^T and dL/dP_b = dL/db, a row [P_A i0..i2, P_b i] a float4
    float W[9], mu[3], gp[PARAMS];
    for (int q = 0; q < 9; ++q) W[q] = coords[q];
    for (int j = 0; j < 3; ++j) mu[j] = coords[9 + j];
    for (int i = 0; i < 3; ++i) {
        for (int l = 0; l < 3; ++l) {
            float t = 0.0f;
            for (int j = 0; j < 3; ++j) t += (total[4 * i + j] - total[4 * i + 3] * mu[j]) * W[3 * l + j];
            gp[4 * i + l] = t;
        }
        gp[4 * i + 3] = total[4 * i + 3];
    }
    for (int k = 0; k < photos; ++k) {   // slot 0 of the step: the corrections' own rate
        for (int i = 0; i < 3; ++i) {
            const int at = PARAMS * k + 4 * i;
            float4 mi = vload4(0, m + at), vi = vload4(0, v + at);
            const float4 d = adam_delta(&step, 0, (float4)(step.lr[0]), &mi, &vi,
                                        k == view ? vload4(i, gp) : (float4)(0.0f));
            vstore4(mi, 0, m + at);
            vstore4(vi, 0, v + at);
            // the step back in T's coordinates: dA = dP_A W, db = dP_b - dA mu
            float dA[3];
            for (int j = 0; j < 3; ++j) dA[j] = d.x * W[j] + d.y * W[3 + j] + d.z * W[6 + j];
            for (int j = 0; j < 3; ++j) corrections[at + j] -= dA[j];
            corrections[at + 3] -= d.w - (dA[0] * mu[0] + dA[1] * mu[1] + dA[2] * mu[2]);
        }
    }
    // the anchor: the mean over the photos (in photo order) minus the identity, off every photo
    for (int q = 0; q < PARAMS; ++q) {
        float t = 0.0f;
        for (int k = 0; k < photos; ++k) t += corrections[PARAMS * k + q];
        t = t / photos - (q % 5 == 0 ? 1.0f : 0.0f);   // the identity's ones: q = 0, 5, 10
        for (int k = 0; k < photos; ++k) corrections[PARAMS * k + q] -= t;
    }
}
