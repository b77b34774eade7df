"""The densification window on the device: per Gaussian a row of the strategy's columns (statistics.py),
summed over the views since the last densification step. The strategy owns it: it resets it after each step,
reads it there (and for checkpoints), and hands the backward a WindowFold, the plain description of where and how
a view folds into it; the fold itself runs in the backward (backward/densify_stats.py)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..backward import WindowFold
from ..runtime import DeviceArrays, Runtime
from ..statistics import PIXELGS_DEPTH_FRACTION, StatisticsSpec


class Window:
    def __init__(self, rt: Runtime, spec: StatisticsSpec, extent: float, track_threshold: float = 0.0,
                 rows: DeviceArrays | None = None):
        """extent: the scene's (Pixel-GS' depth factor); track_threshold: DCS tracking (statistics.py); rows:
        another window's rows to share (without_split_sums)."""
        self.rt, self.spec, self.record = rt, spec, spec.window
        self.extent, self.track_threshold = extent, track_threshold
        self.rows = rows if rows is not None else DeviceArrays(rt, {"window": self.record.width})

    def without_split_sums(self) -> Window:
        """The same window (its rows shared) as the views that gather no split sums fold it
        (DC4GSConfig.cost_every): their fold leaves the split costs as they are."""
        return Window(self.rt, replace(self.spec, split_sums=False), self.extent, self.track_threshold, self.rows)

    @property
    def n(self) -> int:
        return self.rows.n

    @property
    def fold(self) -> WindowFold:
        """Where and how the backward folds a view into this window (its rows move when they grow: asked anew
        each view)."""
        return WindowFold(self.rows.buffers["window"], self.record, self.spec.defines(),
                          PIXELGS_DEPTH_FRACTION * self.extent, self.track_threshold)

    def reset(self, n: int) -> None:
        """Zero the accumulators for n Gaussians (after densification, or at the start)."""
        self.rows.resize(n)
        self.rows.zero()

    def download(self) -> dict[str, np.ndarray]:
        """Column name -> (n,) or (n, width) arrays."""
        return self.record.views(self.rows.download_group("window"))

    def upload(self, columns: dict[str, np.ndarray]) -> None:
        """Restore the accumulators (resuming a run)."""
        self.rows.upload({"window": self.record.rows(columns)})
