// window_fold.h: one view's per-Gaussian sums folded into the densification window (what densify_stats.cl
// does per Gaussian, and the rasterizer backward's sum_pairs with -D FOLD_WINDOW, which folds each Gaussian's
// sums as it adds them up: the per-Gaussian sums then never reach memory). The buffers, the window's columns
// and the -D options: see densify_stats.cl.

#ifndef DC4GS_WINDOW_FOLD_H
#define DC4GS_WINDOW_FOLD_H

#include "common.h"
#include "split.h"

REQUIRE_DEFINED(DC_STATS);
REQUIRE_DEFINED(DC_WINDOW);
REQUIRE_DEFINED(SPLIT_CANDIDATES);

// (1 - |(ux, uy)| / n) |(ax, ay)|: the cost of one side; 0 for an empty side.
inline float side_cost(float ux, float uy, float n, float ax, float ay) {
    float kappa = n > 0.f ? sqrt_nocall(ux * ux + uy * uy) / n : 0.f;
    return (1.f - kappa) * sqrt_nocall(ax * ax + ay * ay);
}

// Gaussian i's sums of one view, s (a SUM row), folded into its window row w. Branch-free past the window
// pooling test, and no builtin calls, so the compiler vectorises across work-items: a Gaussian not visible in
// the view (seen = 0) adds zeros (its sums are zero too) and keeps its largest radius.
ALWAYS_INLINE void fold_view_sums(const uint i, const float *s, const float ndc_x, const float ndc_y,
                                  const float depth_scale, const float track_threshold,
                                  __global const int *radius, __global const float *depth,
                                  __global const float *split_geometry, __global float *window) {
#if DC_WINDOW
    // Window pooling rewrites SPLIT_WIDTH x (SPLIT_CANDIDATES + 1) more running sums per Gaussian: for an unseen
    // one that costs more than vectorising saves (2.1 against 1.6 ms at 48k Gaussians), so it returns here.
    if (radius[i] <= 0) return;
#endif
    const float seen = radius[i] > 0 ? 1.f : 0.f;
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
    SPLIT_TOTALS(total, s);
#if DC_WINDOW
    for (int v = 0; v < SPLIT_WIDTH; ++v) total[v] = w[WIN_SIDE_TOTAL + v] += line * total[v];
    for (int k = 0; k < SPLIT_WIDTH * SPLIT_CANDIDATES; ++k) w[WIN_SIDE_LEFT + k] += line * s[SUM_SPLIT + k];
    line = seen;                     // the accumulated sums are costed at every visible view
#define LEFT(k, v) w[WIN_SIDE_LEFT + SPLIT_WIDTH * (k) + SPLIT_##v]
#else
#define LEFT(k, v) s[SUM_SPLIT + SPLIT_WIDTH * (k) + SPLIT_##v]
#endif
#define RIGHT(k, v) (total[SPLIT_##v] - LEFT(k, v))
    for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
        w[WIN_SPLIT_COSTS + k] += line * (
            side_cost(LEFT(k, UX), LEFT(k, UY), LEFT(k, COUNT), LEFT(k, ABS_X), LEFT(k, ABS_Y))
            + side_cost(RIGHT(k, UX), RIGHT(k, UY), RIGHT(k, COUNT), RIGHT(k, ABS_X), RIGHT(k, ABS_Y)));
    }
#undef RIGHT
#undef LEFT
    w[WIN_SKIP_SPLIT] = (w[WIN_VIEWS] >= (float)TRACK_MIN_VIEWS
                         && w[TRACK_TOTAL] < track_threshold * w[TRACK_COUNT]) ? 1.f : 0.f;
#endif
}

#endif
