// adam.h: Adam's step (PyTorch's update rule) on up to four consecutive floats, fused into
// project_backward.cl so that the parameters' gradients are never stored: each gradient steps its parameter
// where it is computed.
//
// AdamStep (records.h, from ADAM_STEP in dc4gs_cl/records.py), passed by value:
//   lr    learning rate of each group (index PARAM_<GROUP>), then lr[ADAM_SH_REST_RATE] for the SH bands
//         above the DC band (the SH group's own rate is its DC band's)
//   c1, c2  bias corrections 1 - beta1^t and 1 - beta2^t of each group's step t
//   beta1, beta2, eps  as PyTorch's Adam
//   stepping  bit g set: group g steps this iteration (3DGS skips the opacities on their resets)
// The host owns the logic (step counts, schedules, which groups step); this is the arithmetic only.

#ifndef DC4GS_ADAM_H
#define DC4GS_ADAM_H

#include "common.h"

// `count` (1 to 4, a constant after inlining) consecutive floats as the lanes of a float4; lanes beyond
// count read as 0 and are not written.
ALWAYS_INLINE float4 load_lanes(__global const float *p, int count) {
    return (float4)(p[0], count > 1 ? p[1] : 0.f, count > 2 ? p[2] : 0.f, count > 3 ? p[3] : 0.f);
}
ALWAYS_INLINE void store_lanes(__global float *p, int count, float4 x) {
    p[0] = x.x;
    if (count > 1) p[1] = x.y;
    if (count > 2) p[2] = x.z;
    if (count > 3) p[3] = x.w;
}

// Adam's moments mi, vi (four lanes) updated by gradients g, and the step they give at rates lr: what the
// parameters lose. Apart from adam_update for a step taken in other coordinates (exposure.cl).
ALWAYS_INLINE float4 adam_delta(const AdamStep *s, int group, float4 lr, float4 *mi, float4 *vi, float4 g) {
    *mi = s->beta1 * *mi + (1.f - s->beta1) * g;
    *vi = s->beta2 * *vi + (1.f - s->beta2) * g * g;
    float4 vh = *vi / s->c2[group];   // sqrt(vh) without a builtin call (an opaque call under PoCL)
    float4 root = vh > 0.f ? vh * rsqrt4_nocall(vh) : (float4)(0.f);
    return (lr / s->c1[group]) * *mi / (root + s->eps);
}

// Steps `count` consecutive parameters (and their moments m, v) by gradients g with rates lr, four lanes at
// once, if the group steps this iteration. Explicit float4 arithmetic: PoCL does not vectorise these
// updates across work-items, and one float at a time they cost twice as much.
ALWAYS_INLINE void adam_update(const AdamStep *s, int group, float4 lr, int count, __global float *param,
                               __global float *m, __global float *v, float4 g) {
    if (!((s->stepping >> group) & 1u)) return;
    float4 mi = load_lanes(m, count), vi = load_lanes(v, count);
    const float4 delta = adam_delta(s, group, lr, &mi, &vi, g);
    store_lanes(m, count, mi);
    store_lanes(v, count, vi);
    store_lanes(param, count, load_lanes(param, count) - delta);
}

#endif
