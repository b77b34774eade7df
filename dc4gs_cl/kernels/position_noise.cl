// position_noise.cl: MCMC densification's position noise (Kheradmand et al. 2024, the SGLD step; gsplat's
// inject_noise_to_position), once an iteration after Adam's step:
//     means += Sigma (z f scaler),   z ~ N(0, I),   f = 1 / (1 + exp(-NOISE_K ((1 - opacity) - NOISE_X0)))
// f is ~1 only for nearly transparent Gaussians (opacity below ~0.005) and ~0 for the rest; Sigma = R diag(s^2)
// R^T is the Gaussian's covariance (world units^2, as gsplat's: its noise_lr makes up the units); scaler is the
// position learning rate times the noise rate.
//
// One work-item per Gaussian. Buffers (N = Gaussian count, float32):
//   io  means          [N*3]  world position, the noise added in place
//   in  log_scales     [N*3], quats [N*4] (any norm; zero: identity), opacity_logits [N]: as in project.cl
// z: Philox4x32-10 (philox.h) at counter (i, iteration, 0, 0), key (seed_lo, seed_hi): its first three normals.
// A void frame (the iteration runs again) adds nothing. A step that is not finite (a huge, nearly transparent
// Gaussian's covariance) is not taken, and a mean stays within +-MAX_ABS_MEAN, where the kernels keep finite.

#include "philox.h"
#include "project.h"

__kernel UNPACKED_WORK_ITEMS
void position_noise(__global const uint *frame, const uint n, const uint iteration, const uint seed_lo,
                const uint seed_hi, const float scaler, __global float *means, __global const float *log_scales,
                __global const float *quats, __global const float *opacity_logits) {
    uint i = get_global_id(0);
    if (i >= n || FRAME_VOID(frame)) return;
    float opacity = 1.0f / (1.0f + exp_poly(-opacity_logits[i]));
    float f = 1.0f / (1.0f + exp_poly(-NOISE_K * ((1.0f - opacity) - NOISE_X0)));
    float4 z = philox_normals((uint4)(i, iteration, 0u, 0u), (uint2)(seed_lo, seed_hi)) * (f * scaler);
    float R[9], M[9];
    rotation_scale(normalized_quat(load_quat(quats, i)), load_scales(log_scales, i), R, M);
    // Sigma z = M (M^T z), M = R diag(s)
    float3 mt = (float3)(M[0] * z.x + M[3] * z.y + M[6] * z.z, M[1] * z.x + M[4] * z.y + M[7] * z.z,
                         M[2] * z.x + M[5] * z.y + M[8] * z.z);
    float3 d = (float3)(M[0] * mt.x + M[1] * mt.y + M[2] * mt.z, M[3] * mt.x + M[4] * mt.y + M[5] * mt.z,
                        M[6] * mt.x + M[7] * mt.y + M[8] * mt.z);
    float3 mu = LOAD3(means, i), moved = mu + d;
    moved = IS_FINITE(moved.x) && IS_FINITE(moved.y) && IS_FINITE(moved.z) ? moved : mu;
    STORE3(clamp(moved, -MAX_ABS_MEAN, MAX_ABS_MEAN), means, i);
}
