// project_backward.cl: from the gradients of the projection's outputs to the parameters' gradients, and,
// with -D FUSED_ADAM=1 (training), Adam's step on each parameter where its gradient is computed, so the
// gradients never reach global memory (adam.h).
//
// One work-item per Gaussian. Buffers (N = Gaussian count, float32 unless stated):
//   in  means, log_scales, quats, opacity_logits, sh: the parameters, as in project.cl; stepped in place
//       with FUSED_ADAM (a work-item reads its Gaussian's parameters before it steps any)
//   in  radius [N]  int, from the forward: 0 = not visible in this view (all its gradients are 0)
//   in  sums   [N*SUM_WIDTH]  from rasterize_backward.cl (the SUM record): dL/dmean2d (px) at SUM_MEAN2D,
//              dL/dconic (a, b, c as stored) at SUM_CONIC, dL/dopacity (after the sigmoid) at
//              SUM_OPACITY (ANTIALIASED: of the opacity times its compensation, as project.cl wrote it), dL/drgb at
//              SUM_RGB
//   FUSED_ADAM=0:  out d_means [N*3], d_log_scales [N*3], d_quats [N*4], d_opacity_logits [N], d_sh [N*SH_COEFFS*3]
//                  (ACCUMULATE=1: in/out, this view's gradients added: a batch's views, optim/batch_gradients.py)
//   FUSED_ADAM=1:  in step (AdamStep); in/out m_<group>, v_<group>: Adam's moments, shaped like the parameters
//   REGULARIZED=1: reg_opacity, reg_scale: MCMC's loss terms opacity_reg mean(opacity) + scale_reg mean(scale) as
//                  opacity_reg / N and scale_reg / 3N; their gradients reach every Gaussian, seen in the view or not
// The chain: conic -> 2D covariance -> (EWA Jacobian, 3D covariance) -> camera-space position, rotation,
// scales; projected mean -> position; colour -> SH coefficients and the view direction -> position.
// No gradient flows through a clamped x/z or y/z, nor through a colour channel clamped at 0 or COLOR_MAX.
// -D DISTORTION: as project.cl's; the chain goes on through the lens model's Jacobian and its derivatives.

#include "project.h"
#include "param_step.h"

REQUIRE_DEFINED(ANTIALIASED);
REQUIRE_DEFINED(REGULARIZED);
REQUIRE_DEFINED(DISTORTION);

// The gradients of visible Gaussian i's parameters; it reads them and writes nothing global. The SH
// coefficients' gradients are basis[k] * v_colour (k below (sh_degree + 1)^2; zero above).
ALWAYS_INLINE void visible_gradients(int i, const Camera cam, int sh_degree, PARAM *means, PARAM *log_scales,
                                     PARAM *quats, PARAM *opacity_logits, PARAM *sh, __global const float *sums,
                                     float3 *g_means, float3 *g_scales, float4 *g_quat, float *g_opacity,
                                     float3 *v_colour, float *basis) {
    __global const float *g = sums + (size_t)i * SUM_WIDTH;
    float2 v_mean = (float2)(g[SUM_MEAN2D], g[SUM_MEAN2D + 1]);
    float3 v_conic = (float3)(g[SUM_CONIC], g[SUM_CONIC + 1], g[SUM_CONIC + 2]);
    float3 v_rgb = (float3)(g[SUM_RGB], g[SUM_RGB + 1], g[SUM_RGB + 2]);

    // Forward quantities again (cheaper than storing them).
    float3 mu = LOAD3(means, i);
    float3 pc = world_to_camera(&cam, mu);
    float4 q_raw = load_quat(quats, i);
    float4 q = normalized_quat(q_raw);
    float3 s = load_scales(log_scales, i);
    float Rq[9], M[9], T[6], TM[6];
    rotation_scale(q, s, Rq, M);
    float2 t_clamped;
    int2 free;
    ewa_jacobian(&cam, pc, T, &t_clamped, &free);
    float3 cov = covariance_2d(T, M, TM);
    float a = cov.x + EWA_DILATION, b = cov.y, c = cov.z + EWA_DILATION;
    float inv_det = 1.f / (a * c - b * b);
    float k0 = c * inv_det, k1 = -b * inv_det, k2 = a * inv_det;   // the conic, as the forward wrote it

    // conic K = Sigma^-1 = (c, -b, a) / det  ->  dL/dSigma = -K (dL/dK) K; G = [[da, db/2], [db/2, dc]].
    // Written with the conic's entries (bounded: the dilated covariance's eigenvalues are >= EWA_DILATION)
    // rather than Sigma's over det^2, whose squares overflow float32 for a Gaussian hundreds of thousands of
    // pixels wide (a huge scale or focal length), turning 0 x Inf into NaN.
    float da = -(v_conic.x * k0 * k0 + v_conic.y * k0 * k1 + v_conic.z * k1 * k1);
    float db = -(2.f * v_conic.x * k0 * k1 + v_conic.y * (k0 * k2 + k1 * k1) + 2.f * v_conic.z * k1 * k2);
    float dc = -(v_conic.x * k1 * k1 + v_conic.y * k1 * k2 + v_conic.z * k2 * k2);
    float o = 1.f / (1.f + exp_poly(-opacity_logits[i]));
#if ANTIALIASED
    // the opacity o x comp, comp = sqrt(s): ds/d(a, b, c) = (1 - s) (k0, 2 k1, k2) - EWA_DILATION / det (1, 0, 1)
    float s_comp;
    float comp = antialias_compensation(cov.x, cov.y, cov.z, inv_det, &s_comp);
    float v_s = g[SUM_OPACITY] * o * 0.5f / (comp + ANTIALIAS_GRAD_EPS);
    da += v_s * ((1.f - s_comp) * k0 - EWA_DILATION * inv_det);
    db += v_s * 2.f * (1.f - s_comp) * k1;
    dc += v_s * ((1.f - s_comp) * k2 - EWA_DILATION * inv_det);
    *g_opacity = g[SUM_OPACITY] * comp * o * (1.f - o);
#else
    *g_opacity = g[SUM_OPACITY] * o * (1.f - o);
#endif
    float G00 = da, G01 = 0.5f * db, G11 = dc;

    // dL/dSigma = T^T G T (symmetric 3x3); dL/dT = 2 G T Sigma = 2 G (TM) M^T.
    float GT[6];   // G T
    for (int col = 0; col < 3; ++col) {
        GT[col] = G00 * T[col] + G01 * T[3 + col];
        GT[3 + col] = G01 * T[col] + G11 * T[3 + col];
    }
    float d_sigma[9];
    for (int r = 0; r < 3; ++r)
        for (int col = 0; col < 3; ++col) d_sigma[3 * r + col] = T[r] * GT[col] + T[3 + r] * GT[3 + col];
    float GTM[6];  // G (T M)
    for (int col = 0; col < 3; ++col) {
        GTM[col] = G00 * TM[col] + G01 * TM[3 + col];
        GTM[3 + col] = G01 * TM[col] + G11 * TM[3 + col];
    }
    float dT[6];   // 2 G T M M^T
    for (int r = 0; r < 2; ++r)
        for (int col = 0; col < 3; ++col)
            dT[3 * r + col] = 2.f * (GTM[3 * r] * M[3 * col] + GTM[3 * r + 1] * M[3 * col + 1] + GTM[3 * r + 2] * M[3 * col + 2]);
#if DISTORTED
    // T = J W, J = A P (ewa_jacobian): A = diag(f) dD/du at the clamped u = t, P = [[1/z, 0, -tx/z], [0, 1/z, -ty/z]].
    float dJ[6];   // dL/dJ = dT W^T
    for (int r = 0; r < 2; ++r)
        for (int col = 0; col < 3; ++col)
            dJ[3 * r + col] = dT[3 * r] * cam.R[3 * col] + dT[3 * r + 1] * cam.R[3 * col + 1] + dT[3 * r + 2] * cam.R[3 * col + 2];
    float rz = 1.f / pc.z, rz2 = rz * rz, tx = t_clamped.x, ty = t_clamped.y;
    float3 hx, hy, jd = distort_jacobian(&cam, t_clamped, &hx, &hy);
    float a00 = cam.fx * jd.x, a01 = cam.fx * jd.y, a10 = cam.fy * jd.y, a11 = cam.fy * jd.z;
    // dL/dP[c][k] = sum_r A[r][c] dJ[r][k] (its non-constant entries); dL/d(j00, j01, j11) through A
    float dP00 = a00 * dJ[0] + a10 * dJ[3], dP11 = a01 * dJ[1] + a11 * dJ[4];
    float dP02 = a00 * dJ[2] + a10 * dJ[5], dP12 = a01 * dJ[2] + a11 * dJ[5];
    float g00 = cam.fx * (dJ[0] - dJ[2] * tx) * rz, g11 = cam.fy * (dJ[4] - dJ[5] * ty) * rz;
    float g01 = (cam.fx * (dJ[1] - dJ[2] * ty) + cam.fy * (dJ[3] - dJ[5] * tx)) * rz;
    float dtx = free.x ? -dP02 * rz + g00 * hx.x + g01 * hx.y + g11 * hx.z : 0.f;
    float dty = free.y ? -dP12 * rz + g00 * hy.x + g01 * hy.y + g11 * hy.z : 0.f;
    // the mean f D(u) + c at the unclamped u: dL/du = (f v_mean)^T dD/du
    float2 u = (float2)(pc.x * rz, pc.y * rz);
    float3 jm = distort_jacobian(&cam, u, 0, 0);
    dtx += v_mean.x * cam.fx * jm.x + v_mean.y * cam.fy * jm.y;
    dty += v_mean.x * cam.fx * jm.y + v_mean.y * cam.fy * jm.z;
    // u = (x/z, y/z) (t = u wherever t's gradient is not 0)
    float3 dpc = (float3)(dtx * rz, dty * rz,
                          (dP02 * tx + dP12 * ty - dP00 - dP11) * rz2 - (dtx * u.x + dty * u.y) * rz);
#else
    // T = J W  ->  dL/dJ = dT W^T; J has entries (0,0), (0,2), (1,1), (1,2).
    float dJ00 = dT[0] * cam.R[0] + dT[1] * cam.R[1] + dT[2] * cam.R[2];
    float dJ02 = dT[0] * cam.R[6] + dT[1] * cam.R[7] + dT[2] * cam.R[8];
    float dJ11 = dT[3] * cam.R[3] + dT[4] * cam.R[4] + dT[5] * cam.R[5];
    float dJ12 = dT[3] * cam.R[6] + dT[4] * cam.R[7] + dT[5] * cam.R[8];

    // Camera-space position: through J (x/z, y/z only where unclamped) and the projected mean.
    float rz = 1.f / pc.z, rz2 = rz * rz;
    float dtx_dx = free.x ? rz : 0.f, dtx_dz = free.x ? -pc.x * rz2 : 0.f;
    float dty_dy = free.y ? rz : 0.f, dty_dz = free.y ? -pc.y * rz2 : 0.f;
    float3 dpc;
    dpc.x = -dJ02 * cam.fx * rz * dtx_dx + v_mean.x * cam.fx * rz;
    dpc.y = -dJ12 * cam.fy * rz * dty_dy + v_mean.y * cam.fy * rz;
    dpc.z = -dJ00 * cam.fx * rz2 + dJ02 * (cam.fx * t_clamped.x * rz2 - cam.fx * rz * dtx_dz)
            - dJ11 * cam.fy * rz2 + dJ12 * (cam.fy * t_clamped.y * rz2 - cam.fy * rz * dty_dz)
            - (v_mean.x * cam.fx * pc.x + v_mean.y * cam.fy * pc.y) * rz2;
#endif
    float3 dmu = (float3)(cam.R[0] * dpc.x + cam.R[3] * dpc.y + cam.R[6] * dpc.z,
                          cam.R[1] * dpc.x + cam.R[4] * dpc.y + cam.R[7] * dpc.z,
                          cam.R[2] * dpc.x + cam.R[5] * dpc.y + cam.R[8] * dpc.z);

    // Sigma = M M^T, M = Rq diag(s): dM = 2 dSigma M; scales and rotation.
    float dM[9];
    for (int r = 0; r < 3; ++r)
        for (int col = 0; col < 3; ++col)
            dM[3 * r + col] = 2.f * (d_sigma[3 * r] * M[col] + d_sigma[3 * r + 1] * M[3 + col] + d_sigma[3 * r + 2] * M[6 + col]);
    float3 ds = (float3)(dM[0] * Rq[0] + dM[3] * Rq[3] + dM[6] * Rq[6],
                         dM[1] * Rq[1] + dM[4] * Rq[4] + dM[7] * Rq[7],
                         dM[2] * Rq[2] + dM[5] * Rq[5] + dM[8] * Rq[8]);
    *g_scales = ds * s;
    float dR[9];
    for (int r = 0; r < 3; ++r) { dR[3 * r] = dM[3 * r] * s.x; dR[3 * r + 1] = dM[3 * r + 1] * s.y; dR[3 * r + 2] = dM[3 * r + 2] * s.z; }
    float w = q.x, x = q.y, y = q.z, z = q.w;
    float4 dq = 2.f * (float4)(
        -z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7],
        y * dR[1] + z * dR[2] + y * dR[3] - 2.f * x * dR[4] - w * dR[5] + z * dR[6] + w * dR[7] - 2.f * x * dR[8],
        -2.f * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] - w * dR[6] + z * dR[7] - 2.f * y * dR[8],
        -2.f * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - 2.f * z * dR[4] + y * dR[5] + x * dR[6] + y * dR[7]);
    float qn2 = q_raw.x * q_raw.x + q_raw.y * q_raw.y + q_raw.z * q_raw.z + q_raw.w * q_raw.w;
    // Through the normalisation q / |q| (no gradient for a zero quaternion).
    *g_quat = qn2 > QUAT_NORM2_MIN ? (dq - q * (q.x * dq.x + q.y * dq.y + q.z * dq.z + q.w * dq.w)) * rsqrt_nocall(qn2)
                        : (float4)(0.f);

    // SH colour along the view direction; no gradient through a channel clamped at 0 or COLOR_MAX.
    float3 v = mu - (float3)(cam.campos[0], cam.campos[1], cam.campos[2]);
    float inv_len = rsqrt_nocall(DOT3(v, v));
    float3 dir = v * inv_len;
    __global const float *coef = sh + (size_t)i * SH_COEFFS * 3;
    float3 raw = sh_colour(sh_degree, coef, dir);
#define UNCLAMPED(c) ((c) > 0.f && (c) < COLOR_MAX)
    float3 vr = (float3)(UNCLAMPED(raw.x) ? v_rgb.x : 0.f, UNCLAMPED(raw.y) ? v_rgb.y : 0.f, UNCLAMPED(raw.z) ? v_rgb.z : 0.f);
    *v_colour = vr;
    float gx[16], gy[16], gz[16];
    sh_basis(sh_degree, dir, basis);
    sh_basis_gradient(sh_degree, dir, gx, gy, gz);
    int k_active = (sh_degree + 1) * (sh_degree + 1);
    float3 d_dir = (float3)(0.f);
    for (int k = 0; k < k_active; ++k) d_dir += DOT3(LOAD3(coef, k), vr) * (float3)(gx[k], gy[k], gz[k]);
    *g_means = dmu + (d_dir - dir * DOT3(dir, d_dir)) * inv_len;
}


__kernel UNPACKED_WORK_ITEMS
void project_backward(__global const uint *frame, const int n, const Camera cam, const int sh_degree,
                      PARAM *means, PARAM *log_scales, PARAM *quats, PARAM *opacity_logits, PARAM *sh,
                      __global const int *radius, __global const float *sums,
#if REGULARIZED
                      const float reg_opacity, const float reg_scale,
#endif
#if FUSED_ADAM
                      const AdamStep step,
                      __global float *m_means, __global float *v_means,
                      __global float *m_log_scales, __global float *v_log_scales,
                      __global float *m_quats, __global float *v_quats,
                      __global float *m_opacity_logits, __global float *v_opacity_logits,
                      __global float *m_sh, __global float *v_sh
#else
                      __global float *d_means, __global float *d_log_scales, __global float *d_quats,
                      __global float *d_opacity_logits, __global float *d_sh
#endif
                      ) {
    int i = get_global_id(0);
    if (i >= n || FRAME_VOID(frame)) return;   // a void frame: parameters and moments stay as they were
    // Not visible: zero gradients (Adam still steps, on its moments alone). One emit section for both.
    float3 g_means = (float3)(0.f), g_scales = (float3)(0.f), v_colour = (float3)(0.f);
    float4 g_quat = (float4)(0.f);
    float g_opacity = 0.f, basis[16];
    int visible = radius[i] > 0;
    if (visible)   // reads Gaussian i's parameters, before any of them is stepped below
        visible_gradients(i, cam, sh_degree, means, log_scales, quats, opacity_logits, sh, sums, &g_means,
                          &g_scales, &g_quat, &g_opacity, &v_colour, basis);
#if REGULARIZED
    ADD_REGULARIZERS(i, g_opacity, g_scales);
#endif
    int k_active = visible ? (sh_degree + 1) * (sh_degree + 1) : 0;
    float g_sh[SH_FLOATS_PADDED];
    for (int k = 0; k < SH_COEFFS; ++k) STORE3(k < k_active ? basis[k] * v_colour : (float3)(0.f), g_sh, k);
    for (int f = SH_FLOATS; f < SH_FLOATS_PADDED; ++f) g_sh[f] = 0.f;
    STEP_GAUSSIAN(i, g_means, g_scales, g_quat, g_opacity, g_sh);
}
