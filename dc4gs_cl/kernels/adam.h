// adam.h: one Adam step (PyTorch's update rule) on one float, fused into project_backward.cl so that the
// parameters' gradients are never stored: each gradient steps its parameter where it is computed.
//
// AdamStep, passed by value; keep in step with ADAM_STEP_DTYPE in dc4gs_cl/host/adam.py.
//   lr[ADAM_RATES]  learning rate of each group (ADAM_* below); the SH group has two: its DC band and the rest
//   c1[ADAM_GROUPS], c2[ADAM_GROUPS]  bias corrections 1 - beta1^t and 1 - beta2^t of each group's step t
//   beta1, beta2, eps  as PyTorch's Adam
//   stepping  bit g set: group g steps this iteration (3DGS skips the opacities on their resets)
// The host owns the logic (step counts, schedules, which groups step); this is the arithmetic only.

#ifndef DC4GS_ADAM_H
#define DC4GS_ADAM_H

#include "common.h"

#define ADAM_MEANS 0
#define ADAM_SCALES 1
#define ADAM_QUATS 2
#define ADAM_OPACITY 3
#define ADAM_SH 4
#define ADAM_GROUPS 5
#define ADAM_SH_REST 5   // the rate of the SH bands above the DC band
#define ADAM_RATES 6

typedef struct {
    float lr[ADAM_RATES];
    float c1[ADAM_GROUPS];
    float c2[ADAM_GROUPS];
    float beta1, beta2, eps;
    uint stepping;
} AdamStep;

// Steps param (with its moments m, v) by gradient g, if the group steps this iteration.
ALWAYS_INLINE void adam_update(const AdamStep *s, int group, float lr, __global float *param,
                               __global float *m, __global float *v, float g) {
    if (!((s->stepping >> group) & 1u)) return;
    float mi = s->beta1 * *m + (1.f - s->beta1) * g;
    float vi = s->beta2 * *v + (1.f - s->beta2) * g * g;
    *m = mi;
    *v = vi;
    float vh = vi / s->c2[group];   // sqrt(vh) without a builtin call, so the kernel vectorises on PoCL
    *param -= (lr / s->c1[group]) * mi / ((vh > 0.f ? vh * rsqrt_nocall(vh) : 0.f) + s->eps);
}

#endif
