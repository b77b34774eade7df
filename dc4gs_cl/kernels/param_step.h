// param_step.h: what becomes of a Gaussian's parameter gradients, chosen by -D options; shared by
// project_backward.cl (the gradients of one view) and batch_gradients.cl (the gradients of a batch of views).
//   FUSED_ADAM=1:  Adam's step on the parameters (adam.h), with the AdamStep `step` and the moments m_<group>,
//                  v_<group> in scope
//   FUSED_ADAM=0:  stored to d_<group>, or with ACCUMULATE=1 added to it (a batch's views summed in launch order)
// STEP_GAUSSIAN(i, g_means, g_scales, g_quat, g_opacity, g_sh) does it for all five groups of Gaussian i; g_sh is
// a private array of SH_FLOATS rounded up to whole float4s, the padding zero.

#ifndef DC4GS_PARAM_STEP_H
#define DC4GS_PARAM_STEP_H

#include "adam.h"

REQUIRE_DEFINED(FUSED_ADAM);
REQUIRE_DEFINED(ACCUMULATE);
REQUIRE_DEFINED(SH_COEFFS);

#define SH_FLOATS (SH_COEFFS * 3)
#define SH_FLOATS_PADDED ((SH_FLOATS + 3) / 4 * 4)

#if FUSED_ADAM
#define PARAM __global float
// EMIT(group, rates, buffer, index, count, gradients): Adam steps the `count` (<= 4) parameters from
// buffer[index] by the gradients' lanes, with the rates' lanes.
#define EMIT(grp, lr, buf, idx, count, g) \
    adam_update(&step, grp, lr, count, buf + (idx), m_##buf + (idx), v_##buf + (idx), g)
#define RATE(grp) ((float4)(step.lr[grp]))
// The SH rates of floats j..j+3 of a row: the first 3 floats are the DC band, with their own rate.
#define SH_RATES(j) ((float4)((j) < 3 ? step.lr[PARAM_SH] : step.lr[ADAM_SH_REST_RATE], \
                              (j) + 1 < 3 ? step.lr[PARAM_SH] : step.lr[ADAM_SH_REST_RATE], \
                              (j) + 2 < 3 ? step.lr[PARAM_SH] : step.lr[ADAM_SH_REST_RATE], step.lr[ADAM_SH_REST_RATE]))
#else
#define PARAM __global const float
#define RATE(grp) 0
#define SH_RATES(j) 0
#if ACCUMULATE
#define EMIT(grp, lr, buf, idx, count, g) \
    store_lanes(d_##buf + (idx), count, load_lanes(d_##buf + (idx), count) + (g))
#else
#define EMIT(grp, lr, buf, idx, count, g) store_lanes(d_##buf + (idx), count, g)
#endif
#endif

#define STEP_GAUSSIAN(i, g_means, g_scales, g_quat, g_opacity, g_sh)                                                \
    do {                                                                                                           \
        EMIT(PARAM_MEANS, RATE(PARAM_MEANS), means, 3 * (i), 3, (float4)(g_means, 0.f));                            \
        EMIT(PARAM_LOG_SCALES, RATE(PARAM_LOG_SCALES), log_scales, 3 * (i), 3, (float4)(g_scales, 0.f));            \
        EMIT(PARAM_QUATS, RATE(PARAM_QUATS), quats, 4 * (i), 4, g_quat);                                            \
        EMIT(PARAM_OPACITY_LOGITS, RATE(PARAM_OPACITY_LOGITS), opacity_logits, i, 1,                                \
             (float4)(g_opacity, 0.f, 0.f, 0.f));                                                                   \
        const size_t sh_row = (size_t)(i) * SH_FLOATS;                                                             \
        for (int j = 0; j < SH_FLOATS; j += 4)                                                                     \
            EMIT(PARAM_SH, SH_RATES(j), sh, sh_row + j, SH_FLOATS - j < 4 ? SH_FLOATS - j : 4,                      \
                 (float4)(g_sh[j], g_sh[j + 1], g_sh[j + 2], g_sh[j + 3]));                                        \
    } while (0)

// MCMC's regularisers (REGULARIZED): reg_opacity mean(opacity) and reg_scale mean(scale), passed as
// opacity_reg / N and scale_reg / 3N: d/dlogit of reg_opacity sigmoid(logit), d/dlog s of reg_scale s, read before
// the parameters step.
#define ADD_REGULARIZERS(i, g_opacity, g_scales)                                                                   \
    do {                                                                                                           \
        float o_reg = 1.f / (1.f + exp_poly(-opacity_logits[i]));                                                  \
        g_opacity += reg_opacity * o_reg * (1.f - o_reg);                                                          \
        g_scales += reg_scale * load_scales(log_scales, i);                                                        \
    } while (0)

#endif
