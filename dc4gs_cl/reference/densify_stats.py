"""Float64 reference of kernels/densify_stats.cl: one view folded into the densification window, written
from ../shared/docs/dc4gs-spec.md sections 2 to 4 (per-view terms, DCC weights, split costs, both
poolings) as whole-array NumPy, one statement per window column."""
from __future__ import annotations

import numpy as np

from ..statistics import (ABS, DC_WINDOW_COLUMNS, DCC_ABS, DCC_GRAD, DCC_PIX, GRAD, MAX_RADIUS, PIX, PIX_GRAD,
                           SIDE_LEFT, SIDE_TOTAL, SKIP_SPLIT, SPLIT_COSTS, SPLIT_SUMS, VIEWS)
from .dc4gs import directional_consistency, side_cost


def fold_view_reference(window: dict[str, np.ndarray], sums: dict[str, np.ndarray], radius, depth, line,
                        width: int, height: int, depth_scale: float, window_pooling: bool,
                        track_threshold: float = 0.0, tracked: tuple[str, str] = (GRAD, VIEWS),
                        track_min_views: int = 5) -> dict[str, np.ndarray]:
    """The window after one more view.

    window: column -> (n,) or (n, k) float64 accumulators (the columns of the strategy's StatisticsSpec;
    DC4GS' and DCS' columns only where present); sums: the view's per-Gaussian sums by field (mean2d in px;
    abs, pixels; dc and split where gathered); radius, depth: the projection's; line: (n,) bool, the view gave
    the Gaussian a split line; tracked: the split criterion's (total, count) columns."""
    out = {k: np.array(v, np.float64) for k, v in window.items()}
    vis = np.asarray(radius) > 0
    add = lambda key, value: out.__setitem__(key, out[key] + np.where(vis.reshape(-1, *[1] * (np.ndim(value) - 1)),
                                                                       value, 0.0))
    s = {k: np.asarray(v, np.float64) for k, v in sums.items()}
    g = np.hypot(s["mean2d"][:, 0] * width / 2, s["mean2d"][:, 1] * height / 2)     # |sum g|, NDC units
    ghat = np.hypot(s["abs"][:, 0], s["abs"][:, 1])
    pix = s["pixels"]
    f = np.minimum(1.0, (np.asarray(depth, np.float64) / depth_scale) ** 2)
    add(GRAD, g)
    add(ABS, ghat)
    add(VIEWS, np.ones_like(g))
    add(PIX_GRAD, f * g * pix)
    add(PIX, pix)
    out[MAX_RADIUS] = np.where(vis, np.maximum(out[MAX_RADIUS], radius), out[MAX_RADIUS])
    if DCC_ABS in out:
        u = s["dc"]
        if window_pooling:
            for k, col in enumerate(DC_WINDOW_COLUMNS):
                add(col, u[:, k])
            u = np.stack([out[col] for col in DC_WINDOW_COLUMNS], 1)
        weight = np.where(u[:, 2] > 0, 1 - directional_consistency(u[:, :2], u[:, 2]), 0.0)   # 1 - kappa
        add(DCC_ABS, weight * ghat)
        add(DCC_GRAD, weight * g)
        add(DCC_PIX, weight * f * g * pix)
    if SPLIT_COSTS in out:
        n, candidates = out[SPLIT_COSTS].shape
        left = s["split"].reshape(n, candidates, SPLIT_SUMS)
        total = np.concatenate([s["dc"], s["abs"]], 1)
        line = np.asarray(line, bool)
        if window_pooling:   # the sides' sums accumulate; every visible view adds the cost of the accumulated sums
            out[SIDE_TOTAL] = out[SIDE_TOTAL] + np.where((vis & line)[:, None], total, 0.0)
            out[SIDE_LEFT] = out[SIDE_LEFT] + np.where((vis & line)[:, None], left.reshape(n, -1), 0.0)
            total, left, costed = out[SIDE_TOTAL], out[SIDE_LEFT].reshape(n, candidates, SPLIT_SUMS), vis
        else:
            costed = vis & line
        cost = side_cost(left) + side_cost(total[:, None, :] - left)
        out[SPLIT_COSTS] = out[SPLIT_COSTS] + np.where(costed[:, None], cost, 0.0)
        criterion_low = out[tracked[0]] < track_threshold * out[tracked[1]]
        skip = (out[VIEWS] >= track_min_views) & criterion_low
        out[SKIP_SPLIT] = np.where(vis, skip.astype(np.float64), out[SKIP_SPLIT])
    return out
