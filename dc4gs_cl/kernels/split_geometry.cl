// split_geometry.cl: where a Gaussian's split candidates (DC4GS' DC-guided split) fall in this view.
//
// The candidates lie on the principal axis: a = the first axis of largest scale, sigma = its scale,
// p = R e_a; candidate k = 0 .. N-1 (N = SPLIT_CANDIDATES, odd) at mu + (k - (N-1)/2) * 6 sigma / (N+1) * p,
// and the axis' end at mu + 3 sigma p. Projected with project_point (the projection of the centres), they
// lie on one image line, in order. A pixel q is left of candidate k exactly when t(q) < t_k, with
// t(q) = dot(q - c0, dir), c0 the first candidate's pixel and dir the unit direction to the end's pixel, so
// every candidate's sides follow from one scalar per pixel (a pixel with t(q) == t_k counts as right, as in
// the paper's algorithm 3).
//   in  means, log_scales, quats: the parameters; radius [N] int: 0 = not visible (no geometry)
//   in  min_scale: only a Gaussian whose largest scale exceeds this can be split (smaller ones are cloned),
//       so only those get a line and cost the rasterizer backward split terms
//   in  window [N*WIN_WIDTH]: from densify_stats.cl; no line where its WIN_SKIP_SPLIT flag is set
//   out geometry [N*GEO_WIDTH] float, px, the GEO record (dc4gs_cl/backward/split_geometry.py):
//       GEO_ORIGIN c0 (2), GEO_DIR dir (2), GEO_T t_1 .. t_{N-1} (t_0 = 0);
//       dir = (0, 0) where there is no usable line: too small to split, not visible, a candidate or the end at or behind
//       the near plane, or the projected axis shorter than MIN_SPLIT_LINE_PX. The rasterizer backward then adds no
//       split terms for the Gaussian in this view.

#include "project.h"

__kernel void split_geometry(const int n, const Camera cam, const float min_scale, __global const float *means,
                             __global const float *log_scales, __global const float *quats,
                             __global const int *radius, __global const float *window, __global float *geometry) {
    int i = get_global_id(0);
    if (i >= n) return;
    __global float *out = geometry + (size_t)i * GEO_WIDTH;
    out[GEO_DIR] = out[GEO_DIR + 1] = 0.f;
    if (radius[i] <= 0 || window[(size_t)i * WIN_WIDTH + WIN_SKIP_SPLIT] != 0.f) return;
    float3 s = load_scales(log_scales, i);
    int a = s.y > s.x ? (s.z > s.y ? 2 : 1) : (s.z > s.x ? 2 : 0);   // ties: the first axis
    float sigma = a == 0 ? s.x : (a == 1 ? s.y : s.z);
    if (!(sigma > min_scale)) return;
    float Rq[9];
    quat_to_rotmat(normalized_quat(load_quat(quats, i)), Rq);
    float3 axis = (float3)(Rq[a], Rq[3 + a], Rq[6 + a]) * sigma;   // sigma p
    float3 mu = LOAD3(means, i);
    float step = 6.f / (float)(SPLIT_CANDIDATES + 1);
    float3 end = world_to_camera(&cam, mu + 3.f * axis);
    float3 first = world_to_camera(&cam, mu - step * (float)(SPLIT_CANDIDATES / 2) * axis);
    if (!(end.z > NEAR_PLANE) || !(first.z > NEAR_PLANE)) return;   // the middle ones lie between these
    float2 c0 = project_point(&cam, first);
    float2 d = project_point(&cam, end) - c0;
    float len2 = d.x * d.x + d.y * d.y;
    if (!(len2 > MIN_SPLIT_LINE_PX * MIN_SPLIT_LINE_PX) || !IS_FINITE(len2)) return;
    float2 dir = d * rsqrt_nocall(len2);
    for (int k = 1; k < SPLIT_CANDIDATES; ++k) {
        float3 ck = world_to_camera(&cam, mu + step * (float)(k - SPLIT_CANDIDATES / 2) * axis);
        float2 q = project_point(&cam, ck) - c0;
        out[GEO_T + k - 1] = q.x * dir.x + q.y * dir.y;
    }
    out[GEO_ORIGIN] = c0.x; out[GEO_ORIGIN + 1] = c0.y; out[GEO_DIR] = dir.x; out[GEO_DIR + 1] = dir.y;
}
