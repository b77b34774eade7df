// densify_stats.cl: fold one view's per-Gaussian sums into the densification window's statistics.
//
// One work-item per Gaussian; a Gaussian not visible in the view (radius 0) changes nothing.
//   in  radius [N] int px, depth [N] view z: from project.cl
//   in  sums   [N*SUM_WIDTH]: from rasterize_backward.cl (SUM_MEAN2D in px; SUM_ABS in NDC units,
//              SUM_PIXELS; with DC4GS SUM_DC and SUM_SPLIT; see that file)
//   in  split_geometry [N*GEO_WIDTH]: from split_geometry.cl (with SPLIT_CANDIDATES)
//   io  window [N*WIN_WIDTH] float, accumulated since the last densification step (the WIN record: offsets
//              are -D options from dc4gs_cl/host/densify/statistics.py, derived, with the SUM record's,
//              from one StatisticsSpec):
//         WIN_GRAD       sum over visible views of |sum_j g_j|, NDC units (3DGS)
//         WIN_ABS        sum over visible views of |(sum_j |g_x|, sum_j |g_y|)|   (AbsGS)
//         WIN_VIEWS      visible views (nu)
//         WIN_PIX_GRAD   sum over visible views of f |sum_j g_j| pix_v, f = min(1, (z / depth_scale)^2) (Pixel-GS)
//         WIN_PIX        sum over visible views of pix_v, the pixels where the Gaussian was blended
//         WIN_MAX_RADIUS largest radius in px (for the screen-size pruning rule)
//       DC4GS (-D DC_STATS), with kappa the directional consistency |sum u| / count (kappa = 1, weight 0,
//       where the count is 0):
//         WIN_DCC_ABS    sum over visible views of (1 - kappa) |(sum |g_x|, sum |g_y|)|  (the DCC term)
//         WIN_DCC_GRAD   sum over visible views of (1 - kappa) |sum_j g_j|    (DCC on the 3DGS base's own term)
//         WIN_DCC_PIX    sum over visible views of (1 - kappa) f |sum_j g_j| pix_v  (... on Pixel-GS's)
//         with -D DC_WINDOW (the authors' release): kappa from the sums since the last densification step,
//         WIN_DC_UX, WIN_DC_UY, WIN_DC_N; without (the paper): kappa of this view alone
//       DC-guided split (-D SPLIT_CANDIDATES = N), only where this view gave the candidates a line
//       (HAS_SPLIT_LINE):
//         WIN_SPLIT_COSTS + k  split cost of candidate k: per view cost(left_k) + cost(total - left_k), with
//                        cost(side) = (1 - kappa_side) |(sum |g_x|, sum |g_y|)| over the side's pixels;
//                        with DC_WINDOW the sides' sums accumulate over the window (WIN_SIDE_LEFT + 5k + v,
//                        WIN_SIDE_TOTAL + v for v = u_x, u_y, count, |g_x|, |g_y|) and every visible view adds
//                        the cost of the accumulated sums
//         WIN_SKIP_SPLIT 1 once the Gaussian has been seen in TRACK_MIN_VIEWS views of the window and its
//                        running split criterion (WIN total TRACK_TOTAL / count TRACK_COUNT) is below
//                        track_threshold: split_geometry.cl then gives it no line, so no split costs are
//                        gathered for it (0, every Gaussian that can be split, is exact)

#include "common.h"

REQUIRE_DEFINED(DC_STATS);
REQUIRE_DEFINED(DC_WINDOW);
REQUIRE_DEFINED(SPLIT_CANDIDATES);

// (1 - |(ux, uy)| / n) |(ax, ay)|: the cost of one side; 0 for an empty side.
inline float side_cost(float ux, float uy, float n, float ax, float ay) {
    float kappa = n > 0.f ? sqrt_nocall(ux * ux + uy * uy) / n : 0.f;
    return (1.f - kappa) * sqrt_nocall(ax * ax + ay * ay);
}

// Branch-free past the bound check (with view pooling), and no builtin calls, so the compiler vectorises across
// work-items: a Gaussian not visible in the view (seen = 0) adds zeros (its sums are zero too) and keeps its
// largest radius.
__kernel void densify_stats(const uint n, const float ndc_x, const float ndc_y, const float depth_scale,
                            const float track_threshold,
                            __global const int *radius, __global const float *depth,
                            __global const float *sums, __global const float *split_geometry,
                            __global float *window) {
    uint i = get_global_id(0);
    if (i >= n) return;
#if DC_WINDOW
    // Window pooling rewrites 5 x (SPLIT_CANDIDATES + 1) more running sums per Gaussian: for an unseen one that
    // costs more than vectorising saves (2.1 against 1.6 ms at 48k Gaussians), so it returns here.
    if (radius[i] <= 0) return;
#endif
    const float seen = radius[i] > 0 ? 1.f : 0.f;
    __global const float *s = sums + (size_t)i * SUM_WIDTH;
    __global float *w = window + (size_t)i * WIN_WIDTH;
    float gx = s[SUM_MEAN2D] * ndc_x, gy = s[SUM_MEAN2D + 1] * ndc_y;
    float g = sqrt_nocall(gx * gx + gy * gy);
    float a = sqrt_nocall(s[SUM_ABS] * s[SUM_ABS] + s[SUM_ABS + 1] * s[SUM_ABS + 1]);
    float pixels = s[SUM_PIXELS];
    float f = MINF(1.f, (depth[i] / depth_scale) * (depth[i] / depth_scale));
    w[WIN_GRAD] += seen * g;
    w[WIN_ABS] += seen * a;
    w[WIN_VIEWS] += seen;
    w[WIN_PIX_GRAD] += seen * (f * g * pixels);
    w[WIN_PIX] += seen * pixels;
    w[WIN_MAX_RADIUS] = MAXF(w[WIN_MAX_RADIUS], seen * (float)radius[i]);
#if DC_STATS
    float ux = s[SUM_DC], uy = s[SUM_DC + 1], count = s[SUM_DC + 2];
#if DC_WINDOW
    ux = w[WIN_DC_UX] += seen * ux;
    uy = w[WIN_DC_UY] += seen * uy;
    count = w[WIN_DC_N] += seen * count;
#endif
    // 1 - kappa; 0 where no pixel had a gradient
    float weight = count > 0.f ? 1.f - sqrt_nocall(ux * ux + uy * uy) / count : 0.f;
    w[WIN_DCC_ABS] += seen * (weight * a);
    w[WIN_DCC_GRAD] += seen * (weight * g);
    w[WIN_DCC_PIX] += seen * (weight * f * g * pixels);
#endif
#if SPLIT_CANDIDATES
    __global const float *geo = split_geometry + (size_t)i * GEO_WIDTH;
    float line = seen * (HAS_SPLIT_LINE(geo) ? 1.f : 0.f);
    float total[5] = {s[SUM_DC], s[SUM_DC + 1], s[SUM_DC + 2], s[SUM_ABS], s[SUM_ABS + 1]};
    __global const float *left = s + SUM_SPLIT;
#if DC_WINDOW
    for (int v = 0; v < 5; ++v) total[v] = w[WIN_SIDE_TOTAL + v] += line * total[v];
    for (int k = 0; k < 5 * SPLIT_CANDIDATES; ++k) w[WIN_SIDE_LEFT + k] += line * left[k];
    left = w + WIN_SIDE_LEFT;
    line = seen;                     // the accumulated sums are costed at every visible view
#endif
    for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
        __global const float *l = left + 5 * k;
        w[WIN_SPLIT_COSTS + k] += line * (side_cost(l[0], l[1], l[2], l[3], l[4])
            + side_cost(total[0] - l[0], total[1] - l[1], total[2] - l[2], total[3] - l[3], total[4] - l[4]));
    }
    w[WIN_SKIP_SPLIT] = (w[WIN_VIEWS] >= (float)TRACK_MIN_VIEWS
                         && w[TRACK_TOTAL] < track_threshold * w[TRACK_COUNT]) ? 1.f : 0.f;
#endif
}
