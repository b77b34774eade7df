"""The densification window's fold (kernels/window_fold.h): where and how a view's per-Gaussian statistics are
added into the window, as plain data (WindowFold), and the stage that folds a view's full sums with it
(kernels/densify_stats.cl). sum_pairs runs the same fold as it adds up each Gaussian's slots (sum_pairs.py);
the rasterizer backward picks which (rasterize_backward.py). Its float64 reference is reference/densify_stats.py."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..layout import Record
from ..render.renderer import RenderResult
from ..render.stage import PER_GAUSSIAN_WG, Stage
from ..runtime import Runtime


@dataclass(frozen=True, eq=False)
class WindowFold:
    """Where a view's statistics are folded and how: made by the strategy from its StatisticsSpec
    (densify/window.py); the backward reads it and calls nothing of the host's."""
    rows: cl.Buffer            # the window: n rows of record.width float32, n the Gaussians now
    record: Record             # its columns (StatisticsSpec.window)
    defines: dict[str, int]    # what the fold is built with (StatisticsSpec.defines: the view's sums layout too)
    depth_scale: float         # Pixel-GS' depth factor: nearer than this (PIXELGS_DEPTH_FRACTION x extent) scales down
    track_threshold: float     # DCS tracking: split costs while the running split criterion reaches this (0: always)

    def args(self, res: RenderResult) -> list:
        """The fold's arguments for a view, before the window (densify_stats.cl and sum_pairs.cl take them)."""
        return [np.float32(0.5 * res.width), np.float32(0.5 * res.height), np.float32(self.depth_scale),
                np.float32(self.track_threshold), res.proj.radius, res.proj.depth]

    def download(self, rt: Runtime, n: int) -> dict[str, np.ndarray]:
        """The window's n rows, for --check-finite."""
        return {"window": rt.to_host(self.rows, (n, self.record.width))}


class DensifyStats(Stage):
    FILE, KERNELS = "densify_stats.cl", ("densify_stats",)

    def __call__(self, res: RenderResult, sums: cl.Buffer, split_geometry: cl.Buffer | None, fold: WindowFold) -> None:
        """Add one view to the window: its sums (rows of the layout fold.defines describe) and, with DCS, its split
        geometry."""
        n = res.proj.n
        if n == 0:
            return
        geometry = split_geometry if split_geometry is not None else sums   # unread without split candidates
        self.rt.launch_items("densify_stats", self.kernels(fold.defines)["densify_stats"], n, PER_GAUSSIAN_WG,
                             self.ctx.frame, np.uint32(n), *fold.args(res), sums, geometry, fold.rows)
        self.check(lambda: fold.download(self.rt, n))
