// densify_stats.cl: fold one view's per-Gaussian sums into the densification window's statistics.
//
// One work-item per Gaussian; a Gaussian not visible in the view (radius 0) changes nothing. The fold itself is
// window_fold.h's, which sum_pairs.cl also runs (-D FOLD_WINDOW) for a frame walked in one run; this kernel
// folds the full sums of frames walked in runs of tiles and of the float-atomic backward (--low-memory).
//   in  radius [N] int px, depth [N] view z: from project.cl
//   in  sums   [N*SUM_WIDTH]: from rasterize_backward.cl / sum_pairs.cl (SUM_MEAN2D in px; SUM_ABS in NDC units,
//              SUM_PIXELS; with DC4GS SUM_DC and SUM_SPLIT; see that file)
//   in  split_geometry [N*GEO_WIDTH]: from split_geometry.cl (with SPLIT_CANDIDATES)
//   io  window [N*WIN_WIDTH] float, accumulated since the last densification step (the WIN record: offsets
//              are -D options from dc4gs_cl/statistics.py, derived, with the SUM record's,
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

#include "window_fold.h"

__kernel UNPACKED_WORK_ITEMS
void densify_stats(__global const uint *frame, const uint n, const float ndc_x, const float ndc_y, const float depth_scale,
                   const float track_threshold,
                   __global const int *radius, __global const float *depth,
                   __global const float *sums, __global const float *split_geometry,
                   __global float *window) {
    uint i = get_global_id(0);
    if (i >= n || FRAME_VOID(frame)) return;
    float s[SUM_WIDTH];
    for (int k = 0; k < SUM_WIDTH; ++k) s[k] = sums[(size_t)i * SUM_WIDTH + k];
    fold_view_sums(i, s, ndc_x, ndc_y, depth_scale, track_threshold, radius, depth, split_geometry, window);
}
