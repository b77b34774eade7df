// project.h: per-Gaussian geometry shared by the projection's forward and backward kernels, so both
// always compute the same thing: camera transform, rotation and scale, the EWA Jacobian with its
// clamp, the 2D covariance, and the SH colour (degree <= 3) with its derivative.

#ifndef DC4GS_PROJECT_H
#define DC4GS_PROJECT_H

#include "common.h"

inline float3 world_to_camera(const Camera *cam, float3 mu) {
    return (float3)(cam->R[0] * mu.x + cam->R[1] * mu.y + cam->R[2] * mu.z + cam->t[0],
                    cam->R[3] * mu.x + cam->R[4] * mu.y + cam->R[5] * mu.z + cam->t[1],
                    cam->R[6] * mu.x + cam->R[7] * mu.y + cam->R[8] * mu.z + cam->t[2]);
}

// -D DISTORTION (the kernels that project require it): 0 a pinhole, else the lens model of distortion.h.
#if defined(DISTORTION) && DISTORTION
#include "distortion.h"
#define DISTORTED 1
#else
#define DISTORTED 0
#endif

// Pixel position of a camera-space point (pixel centres at +0.5): the one projection of every 2D point.
inline float2 project_point(const Camera *cam, float3 pc) {
#if DISTORTED
    float2 d = distort(cam, (float2)(pc.x / pc.z, pc.y / pc.z));
    return (float2)(cam->fx * d.x + cam->cx, cam->fy * d.y + cam->cy);
#else
    return (float2)(cam->fx * pc.x / pc.z + cam->cx, cam->fy * pc.y / pc.z + cam->cy);
#endif
}

#if DISTORTED
// Whether a centre lies where the lens model is invertible (|u|^2 <= r2_max): past it a polynomial may fold
// a point from far outside the field back into the image, so such a Gaussian is culled.
inline int in_field(const Camera *cam, float3 pc) {
    float ux = pc.x / pc.z, uy = pc.y / pc.z;
    return ux * ux + uy * uy <= cam->r2_max;
}
#endif

// Row-major rotation matrix of a normalised quaternion (w, x, y, z).
ALWAYS_INLINE void quat_to_rotmat(float4 q, float *R) {
    float w = q.x, x = q.y, y = q.z, z = q.w;
    R[0] = 1.f - 2.f * (y * y + z * z); R[1] = 2.f * (x * y - w * z);       R[2] = 2.f * (x * z + w * y);
    R[3] = 2.f * (x * y + w * z);       R[4] = 1.f - 2.f * (x * x + z * z); R[5] = 2.f * (y * z - w * x);
    R[6] = 2.f * (x * z - w * y);       R[7] = 2.f * (y * z + w * x);       R[8] = 1.f - 2.f * (x * x + y * y);
}

// Unit quaternion; a zero quaternion stands for the identity rotation (and gets no gradient).
inline float4 normalized_quat(float4 q) {
    float n2 = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w;
    return n2 > QUAT_NORM2_MIN ? q * rsqrt_nocall(n2) : (float4)(1.f, 0.f, 0.f, 0.f);
}

inline float4 load_quat(__global const float *quats, int i) {
    return (float4)(quats[4 * i], quats[4 * i + 1], quats[4 * i + 2], quats[4 * i + 3]);
}

// exp of the stored log-scales
inline float3 load_scales(__global const float *log_scales, int i) {
    return (float3)(exp_poly(log_scales[3 * i]), exp_poly(log_scales[3 * i + 1]), exp_poly(log_scales[3 * i + 2]));
}

// M = R(q) diag(s), so that Sigma = M M^T.
ALWAYS_INLINE void rotation_scale(float4 q, float3 s, float *Rq, float *M) {
    quat_to_rotmat(q, Rq);
    for (int r = 0; r < 3; ++r) {
        M[3 * r] = Rq[3 * r] * s.x; M[3 * r + 1] = Rq[3 * r + 1] * s.y; M[3 * r + 2] = Rq[3 * r + 2] * s.z;
    }
}

// T = J W (2x3, row-major): the EWA Jacobian J at the camera-space point pc, with x/z and y/z clamped to
// FOV_CLAMP times the half field of view, times the world-to-camera rotation W. *t_clamped gets the
// clamped (x/z, y/z), *free whether each was inside the limits (gradient flows only then).
// DISTORTED: the local Jacobian of the lens model at the clamped point (as Brush's), J = diag(f) dD/du P with
// P = d(x/z, y/z)/d(x, y, z); the limits are the host's (FOV_CLAMP times the undistorted field).
ALWAYS_INLINE void ewa_jacobian(const Camera *cam, float3 pc, float *T, float2 *t_clamped, int2 *free) {
#if DISTORTED
    float lim_x = cam->lim[0], lim_y = cam->lim[1];
#else
    float lim_x = FOV_CLAMP * 0.5f * (float)cam->width / cam->fx, lim_y = FOV_CLAMP * 0.5f * (float)cam->height / cam->fy;
#endif
    float rz = 1.f / pc.z, ux = pc.x * rz, uy = pc.y * rz;
    float tx = CLAMPF(ux, -lim_x, lim_x), ty = CLAMPF(uy, -lim_y, lim_y);
    *t_clamped = (float2)(tx, ty);
    *free = (int2)(ux > -lim_x && ux < lim_x, uy > -lim_y && uy < lim_y);
#if DISTORTED
    float3 jd = distort_jacobian(cam, *t_clamped, 0, 0);
    float a00 = cam->fx * jd.x, a01 = cam->fx * jd.y, a10 = cam->fy * jd.y, a11 = cam->fy * jd.z;
    float j0[3] = {a00 * rz, a01 * rz, -(a00 * tx + a01 * ty) * rz}, j1[3] = {a10 * rz, a11 * rz, -(a10 * tx + a11 * ty) * rz};
    for (int c = 0; c < 3; ++c) {
        T[c] = j0[0] * cam->R[c] + j0[1] * cam->R[3 + c] + j0[2] * cam->R[6 + c];
        T[3 + c] = j1[0] * cam->R[c] + j1[1] * cam->R[3 + c] + j1[2] * cam->R[6 + c];
    }
#else
    float j00 = cam->fx * rz, j02 = -cam->fx * tx * rz, j11 = cam->fy * rz, j12 = -cam->fy * ty * rz;
    for (int c = 0; c < 3; ++c) {
        T[c] = j00 * cam->R[c] + j02 * cam->R[6 + c];
        T[3 + c] = j11 * cam->R[3 + c] + j12 * cam->R[6 + c];
    }
#endif
}

// 2D covariance (a, b, c) = T Sigma T^T before the dilation (callers add EWA_DILATION to a and c), with TM = T M
// kept for the backward.
ALWAYS_INLINE float3 covariance_2d(const float *T, const float *M, float *TM) {
    for (int r = 0; r < 2; ++r)
        for (int c = 0; c < 3; ++c)
            TM[3 * r + c] = T[3 * r] * M[c] + T[3 * r + 1] * M[3 + c] + T[3 * r + 2] * M[6 + c];
    return (float3)(TM[0] * TM[0] + TM[1] * TM[1] + TM[2] * TM[2],
                    TM[0] * TM[3] + TM[1] * TM[4] + TM[2] * TM[5],
                    TM[3] * TM[3] + TM[4] * TM[4] + TM[5] * TM[5]);
}

// The antialiased mode's opacity factor, sqrt(det(Sigma) / det(Sigma + EWA_DILATION I)) (Mip-Splatting's 2D
// filter, gsplat's rasterize_mode "antialiased"): a dilated Gaussian keeps its integral instead of growing it.
// det(Sigma) from the undilated covariance (a0, b0, c0) (covariance_2d), inv_det the dilated one's inverse
// determinant: from the dilated entries, det - EWA_DILATION (a + c) + EWA_DILATION^2 cancels to float32 noise
// where Sigma is sub-pixel (s << 1: errors of 1e-3 in the opacity, 10% in its alpha extent). Also returns the
// square (s), which the backward needs; 0 where Sigma is degenerate. Scalars, not a float3: Intel's CPU runtime
// (intel-opencl-rt 2026.2) garbles a float3 passed to this non-inlined function.
inline float antialias_compensation(float a0, float b0, float c0, float inv_det, float *s) {
    *s = (a0 * c0 - b0 * b0) * inv_det;
    return sqrt_nocall(MAXF(*s, 0.f));
}

// The real SH basis of degree <= 3 at unit direction d (16 values; unused ones left alone).
ALWAYS_INLINE void sh_basis(int degree, float3 d, float *b) {
    float x = d.x, y = d.y, z = d.z;
    b[0] = SH_C0;
    if (degree < 1) return;
    b[1] = -SH_C1 * y; b[2] = SH_C1 * z; b[3] = -SH_C1 * x;
    if (degree < 2) return;
    float xx = x * x, yy = y * y, zz = z * z;
    b[4] = SH_C2_0 * x * y; b[5] = SH_C2_1 * y * z; b[6] = SH_C2_2 * (2.f * zz - xx - yy);
    b[7] = SH_C2_3 * x * z; b[8] = SH_C2_4 * (xx - yy);
    if (degree < 3) return;
    b[9] = SH_C3_0 * y * (3.f * xx - yy); b[10] = SH_C3_1 * x * y * z; b[11] = SH_C3_2 * y * (4.f * zz - xx - yy);
    b[12] = SH_C3_3 * z * (2.f * zz - 3.f * xx - 3.f * yy); b[13] = SH_C3_4 * x * (4.f * zz - xx - yy);
    b[14] = SH_C3_5 * z * (xx - yy); b[15] = SH_C3_6 * x * (xx - 3.f * yy);
}

// d basis_k / d direction (x, y, z components in gx, gy, gz).
inline void sh_basis_gradient(int degree, float3 d, float *gx, float *gy, float *gz) {
    float x = d.x, y = d.y, z = d.z;
    gx[0] = gy[0] = gz[0] = 0.f;
    if (degree < 1) return;
    gx[1] = 0.f;     gy[1] = -SH_C1; gz[1] = 0.f;
    gx[2] = 0.f;     gy[2] = 0.f;    gz[2] = SH_C1;
    gx[3] = -SH_C1;  gy[3] = 0.f;    gz[3] = 0.f;
    if (degree < 2) return;
    float xx = x * x, yy = y * y, zz = z * z;
    gx[4] = SH_C2_0 * y;         gy[4] = SH_C2_0 * x;         gz[4] = 0.f;
    gx[5] = 0.f;                 gy[5] = SH_C2_1 * z;         gz[5] = SH_C2_1 * y;
    gx[6] = -2.f * SH_C2_2 * x;  gy[6] = -2.f * SH_C2_2 * y;  gz[6] = 4.f * SH_C2_2 * z;
    gx[7] = SH_C2_3 * z;         gy[7] = 0.f;                 gz[7] = SH_C2_3 * x;
    gx[8] = 2.f * SH_C2_4 * x;   gy[8] = -2.f * SH_C2_4 * y;  gz[8] = 0.f;
    if (degree < 3) return;
    gx[9] = 6.f * SH_C3_0 * x * y;                gy[9] = SH_C3_0 * (3.f * xx - 3.f * yy);        gz[9] = 0.f;
    gx[10] = SH_C3_1 * y * z;                     gy[10] = SH_C3_1 * x * z;                       gz[10] = SH_C3_1 * x * y;
    gx[11] = -2.f * SH_C3_2 * x * y;              gy[11] = SH_C3_2 * (4.f * zz - xx - 3.f * yy);  gz[11] = 8.f * SH_C3_2 * y * z;
    gx[12] = -6.f * SH_C3_3 * x * z;              gy[12] = -6.f * SH_C3_3 * y * z;                gz[12] = SH_C3_3 * (6.f * zz - 3.f * xx - 3.f * yy);
    gx[13] = SH_C3_4 * (4.f * zz - 3.f * xx - yy); gy[13] = -2.f * SH_C3_4 * x * y;               gz[13] = 8.f * SH_C3_4 * x * z;
    gx[14] = 2.f * SH_C3_5 * x * z;               gy[14] = -2.f * SH_C3_5 * y * z;                gz[14] = SH_C3_5 * (xx - yy);
    gx[15] = SH_C3_6 * (3.f * xx - 3.f * yy);     gy[15] = -6.f * SH_C3_6 * x * y;                gz[15] = 0.f;
}

// Colour before the clamp at 0: sum_k basis_k(d) c[k] + 0.5, for the coefficients c[K][3] of one Gaussian.
ALWAYS_INLINE float3 sh_colour(int degree, __global const float *c, float3 d) {
    float b[16];
    sh_basis(degree, d, b);
    float3 res = (float3)(0.5f);
    int k_active = (degree + 1) * (degree + 1);
    for (int k = 0; k < k_active; ++k) res += b[k] * LOAD3(c, k);
    return res;
}

#endif
