"""Densification statistics stage (kernels/densify_stats.cl): each view's per-Gaussian sums folded into the
window's accumulators, which live on the device until the next densification step; the host reads them
only there (and for checkpoints). Its float64 reference is reference/densify_stats.py."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pyopencl as cl

from ...render.gaussians import DeviceArrays
from ...render.renderer import RenderResult
from ...render.stage import PER_GAUSSIAN_WG, Stage, StageContext
from .statistics import PIXELGS_DEPTH_FRACTION, StatisticsSpec


class DensifyStats(Stage):
    FILE, KERNELS = "densify_stats.cl", ("densify_stats",)

    def __init__(self, ctx: StageContext, spec: StatisticsSpec, extent: float, track_threshold: float = 0.0,
                 rows: DeviceArrays | None = None):
        """extent: the scene's (Pixel-GS' depth factor); track_threshold: DCS tracking (statistics.py); rows:
        another fold's rows to share (without_split_sums)."""
        super().__init__(ctx)
        self.spec, self.record = spec, spec.window
        self.extent, self.depth_scale = extent, PIXELGS_DEPTH_FRACTION * extent
        self.track_threshold = track_threshold
        self.rows = rows if rows is not None else DeviceArrays(self.rt, {"window": self.record.width})
        self.kernel = self.kernels()["densify_stats"]

    def without_split_sums(self) -> DensifyStats:
        """The same window (its rows shared) as the views that gather no split sums fold it
        (DC4GSConfig.cost_every): their fold leaves the split costs as they are."""
        return DensifyStats(self.ctx, replace(self.spec, split_sums=False), self.extent, self.track_threshold,
                            rows=self.rows)

    def defines(self) -> dict:
        return self.spec.defines()

    @property
    def n(self) -> int:
        return self.rows.n

    @property
    def buffer(self) -> cl.Buffer:
        """(n, record.width) float32 rows, for split_geometry.cl's tracking flag."""
        return self.rows.buffers["window"]

    def reset(self, n: int) -> None:
        """Zero the accumulators for n Gaussians (after densification, or at the start)."""
        self.rows.resize(n)
        self.rows.zero()

    def fold_args(self, res: RenderResult) -> list:
        """The fold's arguments for a view, before the sums (kernels/window_fold.h; the rasterizer backward's
        sum_pairs folds a view with them too, backward/sum_pairs.py)."""
        return [np.float32(0.5 * res.width), np.float32(0.5 * res.height), np.float32(self.depth_scale),
                np.float32(self.track_threshold), res.proj.radius, res.proj.depth]

    def fold(self, res: RenderResult, sums: cl.Buffer, split_geometry: cl.Buffer | None = None) -> None:
        """Add one view: its sums (spec.sums rows) and, with DCS, its split geometry."""
        n = self.n
        if n == 0:
            return
        self.rt.launch_items("densify_stats", self.kernel, n, PER_GAUSSIAN_WG, np.uint32(n), *self.fold_args(res),
                             sums, split_geometry if split_geometry is not None else sums, self.buffer)
        self.folded()

    def folded(self) -> None:
        """After a view's fold (here or in sum_pairs): --check-finite reads the window."""
        self.check(lambda: {"window": self.rows.download_group("window")})

    def download(self) -> dict[str, np.ndarray]:
        """Column name -> (n,) or (n, width) arrays."""
        return self.record.views(self.rows.download_group("window"))

    def upload(self, columns: dict[str, np.ndarray]) -> None:
        """Restore the accumulators (resuming a run)."""
        self.rows.upload({"window": self.record.rows(columns)})
