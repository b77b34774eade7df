// adam.cl: one Adam step on one parameter group, element-wise.
//   param [n] float, updated in place;  grad [n] float;  m, v [n] float: first and second moments,
//   updated in place. The group is rows of `width` floats (one per Gaussian); lanes below `split` of each
//   row step with lr_low, the rest with lr_high (the SH group: DC band and higher bands).
//   beta1, beta2, eps: as PyTorch's Adam; c1 = 1 - beta1^t and c2 = 1 - beta2^t (the bias corrections)
//   come from the host, which owns the step count and the schedule.

#include "common.h"

// Launched over (width, rows): dimension 0 is the lane within a Gaussian's row, so no integer division.
__kernel void adam_step(const uint rows, const uint split, const float lr_low, const float lr_high,
                        const float beta1, const float beta2, const float eps, const float c1, const float c2,
                        __global float *param, __global const float *grad, __global float *m, __global float *v) {
    uint lane = get_global_id(0), width = get_global_size(0), row = get_global_id(1);
    if (row >= rows) return;
    uint i = row * width + lane;
    float lr = lane < split ? lr_low : lr_high;
    float g = grad[i];
    float mi = beta1 * m[i] + (1.f - beta1) * g;
    float vi = beta2 * v[i] + (1.f - beta2) * g * g;
    m[i] = mi;
    v[i] = vi;
    float vh = vi / c2;   // sqrt(vh) without a builtin call, so the kernel vectorises (3x faster on PoCL)
    param[i] -= (lr / c1) * mi / ((vh > 0.f ? vh * rsqrt_nocall(vh) : 0.f) + eps);
}
