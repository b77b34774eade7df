// densify_stats.cl: fold one view's per-Gaussian sums into the densification window's statistics.
//
// One work-item per Gaussian; nothing happens for a Gaussian not visible in the view (radius 0).
//   in  radius [N] int px, depth [N] view z: from project.cl
//   in  sums   [N*SUMS_PER_GAUSSIAN]: from rasterize_backward.cl (SUM_MEAN2D in px, SUM_ABS in NDC units,
//              SUM_PIXELS; see that file)
//   io  window [N*WINDOW_WIDTH] float, accumulated since the last densification step (offsets are -D
//              options built by dc4gs_cl/host/stats.py):
//         WIN_GRAD       sum over visible views of |sum_j g_j|, NDC units (3DGS)
//         WIN_ABS        sum over visible views of |(sum_j |g_x|, sum_j |g_y|)|   (AbsGS)
//         WIN_VIEWS      visible views (nu)
//         WIN_PIX_GRAD   sum over visible views of f |sum_j g_j| pix_v, f = min(1, (z / depth_scale)^2) (Pixel-GS)
//         WIN_PIX        sum over visible views of pix_v, the pixels where the Gaussian was blended
//         WIN_MAX_RADIUS largest radius in px (for the screen-size pruning rule)

#include "common.h"

__kernel void accumulate_view_stats(const uint n, const float ndc_x, const float ndc_y, const float depth_scale,
                                    __global const int *radius, __global const float *depth,
                                    __global const float *sums, __global float *window) {
    uint i = get_global_id(0);
    if (i >= n || radius[i] <= 0) return;
    __global const float *s = sums + (size_t)i * SUMS_PER_GAUSSIAN;
    __global float *w = window + (size_t)i * WINDOW_WIDTH;
    float gx = s[SUM_MEAN2D] * ndc_x, gy = s[SUM_MEAN2D + 1] * ndc_y;
    float g = sqrt(gx * gx + gy * gy);
    float pixels = s[SUM_PIXELS];
    float f = MINF(1.f, (depth[i] / depth_scale) * (depth[i] / depth_scale));
    w[WIN_GRAD] += g;
    w[WIN_ABS] += sqrt(s[SUM_ABS] * s[SUM_ABS] + s[SUM_ABS + 1] * s[SUM_ABS + 1]);
    w[WIN_VIEWS] += 1.f;
    w[WIN_PIX_GRAD] += f * g * pixels;
    w[WIN_PIX] += pixels;
    w[WIN_MAX_RADIUS] = MAXF(w[WIN_MAX_RADIUS], (float)radius[i]);
}
