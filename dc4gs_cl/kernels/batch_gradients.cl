// batch_gradients.cl: Adam's step on the parameters from gradients gathered over a batch of views (optim/batch_gradients.py):
// each view's project_backward.cl added its gradients (FUSED_ADAM=0, ACCUMULATE=1), the processes' sums were
// added where several train together (train/parallel.py), and this steps every Gaussian by their mean. Built with
// FUSED_ADAM=1, ACCUMULATE=0.
//
// One work-item per Gaussian. Buffers (N = Gaussian count, float32):
//   in/out means, log_scales, quats, opacity_logits, sh: the parameters, as in project.cl, stepped in place
//   in     d_means [N*3], d_log_scales [N*3], d_quats [N*4], d_opacity_logits [N], d_sh [N*SH_COEFFS*3]: the
//          gradients summed over the batch's views
//   in     grad_scale: 1 / the batch's views (the step takes the mean over them)
//   REGULARIZED=1: reg_opacity, reg_scale as in project_backward.cl, added once per step (not per view)
//   in     step (AdamStep); in/out m_<group>, v_<group>: Adam's moments, shaped like the parameters

#include "project.h"
#include "param_step.h"

REQUIRE_DEFINED(REGULARIZED);

__kernel UNPACKED_WORK_ITEMS
void batch_gradients(__global const uint *frame, const int n,
                     PARAM *means, PARAM *log_scales, PARAM *quats, PARAM *opacity_logits, PARAM *sh,
                     __global const float *d_means, __global const float *d_log_scales,
                     __global const float *d_quats, __global const float *d_opacity_logits,
                     __global const float *d_sh, const float grad_scale,
#if REGULARIZED
                     const float reg_opacity, const float reg_scale,
#endif
                     const AdamStep step,
                     __global float *m_means, __global float *v_means,
                     __global float *m_log_scales, __global float *v_log_scales,
                     __global float *m_quats, __global float *v_quats,
                     __global float *m_opacity_logits, __global float *v_opacity_logits,
                     __global float *m_sh, __global float *v_sh) {
    int i = get_global_id(0);
    if (i >= n || FRAME_VOID(frame)) return;
    float3 g_means = grad_scale * LOAD3(d_means, i);
    float3 g_scales = grad_scale * LOAD3(d_log_scales, i);
    float4 g_quat = grad_scale * load_lanes(d_quats + 4 * i, 4);
    float g_opacity = grad_scale * d_opacity_logits[i];
#if REGULARIZED
    ADD_REGULARIZERS(i, g_opacity, g_scales);
#endif
    float g_sh[SH_FLOATS_PADDED];
    for (int f = 0; f < SH_FLOATS; ++f) g_sh[f] = grad_scale * d_sh[(size_t)i * SH_FLOATS + f];
    for (int f = SH_FLOATS; f < SH_FLOATS_PADDED; ++f) g_sh[f] = 0.f;
    STEP_GAUSSIAN(i, g_means, g_scales, g_quat, g_opacity, g_sh);
}
