// project.cl: per-Gaussian projection to the image (EWA splatting), SH colour and tile counts.
//
// One work-item per Gaussian. Buffers (N = Gaussian count, float32 unless stated):
//   in  means          [N*3]  world position
//   in  log_scales     [N*3]  log of the 3 axis scales
//   in  quats          [N*4]  rotation (w, x, y, z), any norm (normalised here; zero norm -> identity)
//   in  opacity_logits [N]    opacity = sigmoid(logit)
//   in  sh             [N*SH_COEFFS*3]  SH coefficients, coefficient-major, RGB innermost
//   out mean2d         [N*2]  projected centre, px (pixel centres at +0.5)
//   out conic_opacity  [N*4]  (a, b, c) of the inverse 2D covariance (1/px^2; power = -0.5(a dx^2 + c dy^2) - b dx dy),
//                             and the opacity after the sigmoid
//   out rgb            [N*3]  colour from SH along camera -> mean, clamped at 0
//   out depth          [N]    view-space z (world units)
//   out radius         [N]    int, px, ceil(3 sigma_max); 0 = culled, or its 3-sigma box misses the image:
//                             then the Gaussian is not visible in this view
//   out alpha_extent   [N*2]  px, half-width and half-height of the box outside which alpha < ALPHA_MIN
//                             (opacity * exp(-q/2) < ALPHA_MIN for the Mahalanobis q), plus a 0.01 px margin
//   out tiles_touched  [N]    uint, tiles of pair_rect() (common.h): 0 when radius == 0 or opacity < ALPHA_MIN
// -D SH_COEFFS: coefficients stored per channel (1, 4, 9 or 16); the active degree is an argument.

#include "common.h"

// Row-major rotation matrix of a normalised quaternion (w, x, y, z).
inline void quat_to_rotmat(float4 q, float *R) {
    float w = q.x, x = q.y, y = q.z, z = q.w;
    R[0] = 1.f - 2.f * (y * y + z * z); R[1] = 2.f * (x * y - w * z);       R[2] = 2.f * (x * z + w * y);
    R[3] = 2.f * (x * y + w * z);       R[4] = 1.f - 2.f * (x * x + z * z); R[5] = 2.f * (y * z - w * x);
    R[6] = 2.f * (x * z - w * y);       R[7] = 2.f * (y * z + w * x);       R[8] = 1.f - 2.f * (x * x + y * y);
}

inline float4 normalized_quat(float4 q) {
    float n2 = dot(q, q);
    return n2 > 0.f ? q * rsqrt(n2) : (float4)(1.f, 0.f, 0.f, 0.f);
}

// The real SH basis of degree <= 3 evaluated at unit direction d, times the coefficients c[K][3].
inline float3 eval_sh(int degree, __global const float *c, float3 d) {
    float3 res = SH_C0 * vload3(0, c);
    if (degree > 0) {
        float x = d.x, y = d.y, z = d.z;
        res += -SH_C1 * y * vload3(1, c) + SH_C1 * z * vload3(2, c) - SH_C1 * x * vload3(3, c);
        if (degree > 1) {
            float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
            res += SH_C2_0 * xy * vload3(4, c) + SH_C2_1 * yz * vload3(5, c)
                 + SH_C2_2 * (2.f * zz - xx - yy) * vload3(6, c)
                 + SH_C2_3 * xz * vload3(7, c) + SH_C2_4 * (xx - yy) * vload3(8, c);
            if (degree > 2) {
                res += SH_C3_0 * y * (3.f * xx - yy) * vload3(9, c) + SH_C3_1 * xy * z * vload3(10, c)
                     + SH_C3_2 * y * (4.f * zz - xx - yy) * vload3(11, c)
                     + SH_C3_3 * z * (2.f * zz - 3.f * xx - 3.f * yy) * vload3(12, c)
                     + SH_C3_4 * x * (4.f * zz - xx - yy) * vload3(13, c)
                     + SH_C3_5 * z * (xx - yy) * vload3(14, c) + SH_C3_6 * x * (xx - 3.f * yy) * vload3(15, c);
            }
        }
    }
    return res + 0.5f;
}

__kernel void project(const int n, const Camera cam, const int sh_degree, const int tiles_x, const int tiles_y,
                      __global const float *means, __global const float *log_scales,
                      __global const float *quats, __global const float *opacity_logits,
                      __global const float *sh,
                      __global float *mean2d, __global float *conic_opacity, __global float *rgb,
                      __global float *depth, __global int *radius, __global float *alpha_extent,
                      __global uint *tiles_touched) {
    int i = get_global_id(0);
    if (i >= n) return;
    radius[i] = 0;
    tiles_touched[i] = 0;

    float3 mu = vload3(i, means);
    float3 pc = (float3)(cam.R[0] * mu.x + cam.R[1] * mu.y + cam.R[2] * mu.z + cam.t[0],
                         cam.R[3] * mu.x + cam.R[4] * mu.y + cam.R[5] * mu.z + cam.t[1],
                         cam.R[6] * mu.x + cam.R[7] * mu.y + cam.R[8] * mu.z + cam.t[2]);
    depth[i] = pc.z;
    if (!(pc.z > NEAR_PLANE)) return;   // also rejects NaN

    // 3D covariance Sigma = M M^T with M = R S.
    float Rq[9];
    quat_to_rotmat(normalized_quat(vload4(i, quats)), Rq);
    float3 s = exp(vload3(i, log_scales));
    float M[9];
    for (int r = 0; r < 3; ++r) { M[3 * r] = Rq[3 * r] * s.x; M[3 * r + 1] = Rq[3 * r + 1] * s.y; M[3 * r + 2] = Rq[3 * r + 2] * s.z; }

    // EWA: cov2d = T Sigma T^T + dilation, T = J W (2x3), with x/z and y/z clamped to 1.3 x the half FOV.
    float lim_x = FOV_CLAMP * 0.5f * (float)cam.width / cam.fx, lim_y = FOV_CLAMP * 0.5f * (float)cam.height / cam.fy;
    float rz = 1.f / pc.z;
    float tx = CLAMPF(pc.x * rz, -lim_x, lim_x), ty = CLAMPF(pc.y * rz, -lim_y, lim_y);
    float j00 = cam.fx * rz, j02 = -cam.fx * tx * rz, j11 = cam.fy * rz, j12 = -cam.fy * ty * rz;
    float T[6];
    for (int c = 0; c < 3; ++c) {
        T[c] = j00 * cam.R[c] + j02 * cam.R[6 + c];
        T[3 + c] = j11 * cam.R[3 + c] + j12 * cam.R[6 + c];
    }
    // TM = T M (2x3); cov2d = TM TM^T
    float TM[6];
    for (int r = 0; r < 2; ++r)
        for (int c = 0; c < 3; ++c)
            TM[3 * r + c] = T[3 * r] * M[c] + T[3 * r + 1] * M[3 + c] + T[3 * r + 2] * M[6 + c];
    float a = TM[0] * TM[0] + TM[1] * TM[1] + TM[2] * TM[2] + EWA_DILATION;
    float b = TM[0] * TM[3] + TM[1] * TM[4] + TM[2] * TM[5];
    float c = TM[3] * TM[3] + TM[4] * TM[4] + TM[5] * TM[5] + EWA_DILATION;
    float det = a * c - b * b;
    if (!(det > 0.f) || !isfinite(det)) return;
    float inv_det = 1.f / det;

    float mid = 0.5f * (a + c);
    float lambda_max = mid + sqrt(MAXF(MIN_EIGEN_GAP, mid * mid - det));
    float r_px = ceil(RADIUS_SIGMAS * sqrt(lambda_max));
    float2 m2 = (float2)(cam.fx * pc.x * rz + cam.cx, cam.fy * pc.y * rz + cam.cy);
    if (!(r_px > 0.f) || !isfinite(m2.x) || !isfinite(m2.y)) return;
    r_px = MINF(r_px, 1e7f);   // keeps the int conversion defined; the tile rectangle is clamped anyway
    if (rect_area(tile_rect(m2, (float2)(r_px, r_px), tiles_x, tiles_y)) == 0) return;

    float op = 1.f / (1.f + exp(-opacity_logits[i]));
    // alpha >= ALPHA_MIN needs the Mahalanobis distance q <= 2 ln(op / ALPHA_MIN); the box of that
    // ellipse has half-sizes sqrt(q a) and sqrt(q c) (a, c: the 2D covariance's diagonal).
    float q = op >= ALPHA_MIN ? 2.f * log(op / ALPHA_MIN) : 0.f;
    float2 ext = (float2)(sqrt(q * a), sqrt(q * c)) + 0.01f;
    uint tiles = (uint)rect_area(pair_rect(m2, r_px, ext, tiles_x, tiles_y));
#if ALPHA_CUT
    if (op < ALPHA_MIN) tiles = 0;   // alpha = opacity * exp(power) < ALPHA_MIN everywhere
#endif

    float3 dir = normalize(mu - (float3)(cam.campos[0], cam.campos[1], cam.campos[2]));
    float3 col = eval_sh(sh_degree, sh + (size_t)i * (SH_COEFFS * 3), dir);

    vstore2(m2, i, mean2d);
    vstore4((float4)(c * inv_det, -b * inv_det, a * inv_det, op), i, conic_opacity);
    vstore3(max(col, 0.f), i, rgb);
    vstore2(ext, i, alpha_extent);
    radius[i] = (int)r_px;
    tiles_touched[i] = tiles;
}
