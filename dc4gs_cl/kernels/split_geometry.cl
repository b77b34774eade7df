// split_geometry.cl: where a Gaussian's split candidates (DC4GS' DC-guided split) fall in this view.
//
// The candidates lie on the principal axis: a = the first axis of largest scale, sigma = its scale,
// p = R e_a; candidate k = 0 .. N-1 (N = SPLIT_CANDIDATES, odd) at mu + (k - (N-1)/2) * 6 sigma / (N+1) * p,
// and the axis' end at mu + 3 sigma p. Projected with project_point (the projection of the centres), they
// lie on one image line, in order (through a lens model, -D DISTORTION, the axis' image bends slightly: the
// line is the chord from the first candidate's pixel to the end's, each candidate sided by its projection onto
// it). A pixel q is left of candidate k exactly when t(q) < t_k, with
// t(q) = dot(q - c0, dir), c0 the first candidate's pixel and dir the unit direction to the end's pixel, so
// every candidate's sides follow from one scalar per pixel (a pixel with t(q) == t_k counts as right, as in
// the paper's algorithm 3).
//   in  means, log_scales, quats: the parameters; radius [N] int: 0 = not visible (no geometry)
//   in  min_scale: only a Gaussian whose largest scale exceeds this can be split (smaller ones are cloned),
//       so only those get a line and cost the rasterizer backward split terms
//   in  window [N*WIN_WIDTH]: from densify_stats.cl; no line where its WIN_SKIP_SPLIT flag is set
//   out geometry [N*GEO_WIDTH] float, px, the GEO record (dc4gs_cl/backward/split_geometry.py):
//       GEO_ORIGIN c0 (2), GEO_DIR dir (2), GEO_T t_1 .. t_{N-1} (t_0 = 0), all 0 where there is no line;
//       dir = (0, 0) where there is no usable line: too small to split, not visible, a candidate or the end at or behind
//       the near plane, or the projected axis shorter than MIN_SPLIT_LINE_PX. The rasterizer backward then adds no
//       split terms for the Gaussian in this view.

#include "project.h"

REQUIRE_DEFINED(DISTORTION);   // the candidates go through the view's lens model (project_point)

// Branch-free past the bound check: every work-item computes a line and the tests (`line`) only choose what it
// writes (zeros where there is no line), so the compiler vectorises across work-items (2x faster on PoCL than
// returning early).
__kernel void split_geometry(const int n, const Camera cam, const float min_scale, __global const float *means,
                             __global const float *log_scales, __global const float *quats,
                             __global const int *radius, __global const float *window, __global float *geometry) {
    int i = get_global_id(0);
    if (i >= n) return;
    float3 log_s = LOAD3(log_scales, i);
    // The largest of the log scales (ties: the first axis), as geometry.principal_axis picks it; one exp, not
    // three: 1.56 -> 1.24 ms at 48k Gaussians on PoCL.
    int a = log_s.y > log_s.x ? (log_s.z > log_s.y ? 2 : 1) : (log_s.z > log_s.x ? 2 : 0);
    float sigma = exp_poly(a == 0 ? log_s.x : (a == 1 ? log_s.y : log_s.z));
    float Rq[9];
    quat_to_rotmat(normalized_quat(load_quat(quats, i)), Rq);
    // sigma p: column a of R (selects, not Rq[a]: an index known only at run time keeps Rq in memory)
    float3 axis = sigma * (float3)(a == 0 ? Rq[0] : (a == 1 ? Rq[1] : Rq[2]), a == 0 ? Rq[3] : (a == 1 ? Rq[4] : Rq[5]),
                                   a == 0 ? Rq[6] : (a == 1 ? Rq[7] : Rq[8]));
    float3 mu = LOAD3(means, i);
    float step = 6.f / (float)(SPLIT_CANDIDATES + 1);
    float3 end = world_to_camera(&cam, mu + 3.f * axis);
    float3 first = world_to_camera(&cam, mu - step * (float)(SPLIT_CANDIDATES / 2) * axis);
    float2 c0 = project_point(&cam, first);
    float2 d = project_point(&cam, end) - c0;
    float len2 = d.x * d.x + d.y * d.y;
    // The middle candidates lie between the first and the end, so these two decide the near plane.
    // (& rather than &&: no branch, so the loads are not conditional either)
    int line = (radius[i] > 0) & (window[(size_t)i * WIN_WIDTH + WIN_SKIP_SPLIT] == 0.f) & (sigma > min_scale)
               & (end.z > NEAR_PLANE) & (first.z > NEAR_PLANE) & (len2 > MIN_SPLIT_LINE_PX * MIN_SPLIT_LINE_PX)
               & IS_FINITE(len2);
    float2 dir = d * rsqrt_nocall(line ? len2 : 1.f);
    __global float *out = geometry + (size_t)i * GEO_WIDTH;
    for (int k = 1; k < SPLIT_CANDIDATES; ++k) {
        float3 ck = world_to_camera(&cam, mu + step * (float)(k - SPLIT_CANDIDATES / 2) * axis);
        float2 q = project_point(&cam, ck) - c0;
        out[GEO_T + k - 1] = line ? q.x * dir.x + q.y * dir.y : 0.f;
    }
    out[GEO_ORIGIN] = line ? c0.x : 0.f; out[GEO_ORIGIN + 1] = line ? c0.y : 0.f;
    out[GEO_DIR] = line ? dir.x : 0.f; out[GEO_DIR + 1] = line ? dir.y : 0.f;
}
