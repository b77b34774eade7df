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
//                             and the opacity after the sigmoid (ANTIALIASED: times antialias_compensation)
//   out rgb            [N*3]  colour from SH along camera -> mean, clamped to [0, COLOR_MAX]
//   out depth          [N]    view-space z (world units)
//   out radius         [N]    int, px, ceil(3 sigma_max); 0 = culled, or its 3-sigma box misses the image:
//                             then the Gaussian is not visible in this view
//   out alpha_extent   [N*2]  px, half-width and half-height of the box outside which alpha < ALPHA_MIN
//                             (opacity * exp(-q/2) < ALPHA_MIN for the Mahalanobis q), plus ALPHA_EXTENT_MARGIN px
//   out tiles_touched  [N]    uint, tiles of pair_rect() (tiles.h): 0 when radius == 0, or (ALPHA_CUT) opacity < ALPHA_MIN
// -D SH_COEFFS: coefficients stored per channel (1, 4, 9 or 16); the active degree is an argument.
// -D ANTIALIASED: 1 scales each opacity by antialias_compensation (project.h), the antialiased mode.
// -D DISTORTION: 0 a pinhole camera; 1, 2 the lens models of distortion.h: the centre through the model, the 2D
//    covariance through its local Jacobian, a centre outside the model's invertible field culled (in_field).

#include "project.h"
#include "tiles.h"

REQUIRE_DEFINED(ANTIALIASED);
REQUIRE_DEFINED(DISTORTION);

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

    float3 mu = LOAD3(means, i);
    float3 pc = world_to_camera(&cam, mu);
    depth[i] = pc.z;
    if (!(pc.z > NEAR_PLANE)) return;   // also rejects NaN
#if DISTORTED
    if (!in_field(&cam, pc)) return;
#endif

    float Rq[9], M[9], T[6], TM[6];
    rotation_scale(normalized_quat(load_quat(quats, i)), load_scales(log_scales, i), Rq, M);
    float2 t_clamped;
    int2 free;
    ewa_jacobian(&cam, pc, T, &t_clamped, &free);
    float3 cov = covariance_2d(T, M, TM);
    float a = cov.x + EWA_DILATION, b = cov.y, c = cov.z + EWA_DILATION;
    float det = a * c - b * b;
    if (!(det > 0.f) || !IS_FINITE(det)) return;
    float inv_det = 1.f / det;

    float mid = 0.5f * (a + c);
    float lambda_max = mid + sqrt_nocall(MAXF(MIN_EIGEN_GAP, mid * mid - det));
    // capped at 1e7 px: keeps the int conversion defined; the tile rectangle is clamped anyway
    float r_px = ceil_nonnegative(MINF(RADIUS_SIGMAS * sqrt_nocall(lambda_max), 1e7f));
    float2 m2 = project_point(&cam, pc);
    if (!(r_px > 0.f) || !IS_FINITE(m2.x) || !IS_FINITE(m2.y)) return;
    if (rect_area(tile_rect(m2, (float2)(r_px, r_px), tiles_x, tiles_y)) == 0) return;

    float op = 1.f / (1.f + exp_poly(-opacity_logits[i]));
#if ANTIALIASED
    float square;
    op *= antialias_compensation(cov.x, cov.y, cov.z, inv_det, &square);
#endif
    // alpha >= ALPHA_MIN needs the Mahalanobis distance q <= 2 ln(op / ALPHA_MIN); the box of that
    // ellipse has half-sizes sqrt(q a) and sqrt(q c) (a, c: the 2D covariance's diagonal).
    float q = op >= ALPHA_MIN ? 2.f * log_nocall(op / ALPHA_MIN) : 0.f;
    float2 ext = (float2)(sqrt_nocall(q * a), sqrt_nocall(q * c)) + ALPHA_EXTENT_MARGIN;
    uint tiles = (uint)rect_area(pair_rect(m2, r_px, ext, tiles_x, tiles_y));
#if ALPHA_CUT
    if (op < ALPHA_MIN) tiles = 0;   // alpha = opacity * exp(power) < ALPHA_MIN everywhere
#endif

    float3 v = mu - (float3)(cam.campos[0], cam.campos[1], cam.campos[2]);
    float3 dir = v * rsqrt_nocall(DOT3(v, v));
    float3 col = sh_colour(sh_degree, sh + (size_t)i * (SH_COEFFS * 3), dir);

    mean2d[2 * i] = m2.x; mean2d[2 * i + 1] = m2.y;
    conic_opacity[4 * i] = c * inv_det; conic_opacity[4 * i + 1] = -b * inv_det;
    conic_opacity[4 * i + 2] = a * inv_det; conic_opacity[4 * i + 3] = op;
    STORE3((float3)(CLAMPF(col.x, 0.f, COLOR_MAX), CLAMPF(col.y, 0.f, COLOR_MAX), CLAMPF(col.z, 0.f, COLOR_MAX)), rgb, i);
    alpha_extent[2 * i] = ext.x; alpha_extent[2 * i + 1] = ext.y;
    radius[i] = (int)r_px;
    tiles_touched[i] = tiles;
}
