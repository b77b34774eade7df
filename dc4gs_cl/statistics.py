"""What the device gathers for density control, described once: every column, record and lane order below is
the only spelling of it; the kernels read them as -D defines.

- SumsLayout: the per-Gaussian sums the rasterizer backward writes for one view (the SUM record, kernels/
  rasterize_backward.cl): the gradients project_backward reads and the statistics a strategy asks for.
- SPLIT_LANES: a split candidate's sums over the pixels on one side of it, in their order (the SPLIT record).
- geometry_record: where a view's split candidates fall (the GEO record, kernels/split_geometry.cl).
- The window: per Gaussian a row of columns summed over the views in which it was visible since the last
  densification step (the WIN record, kernels/window_fold.h); a strategy reads it through Criterion values.
- StatisticsSpec, made by the strategy, is the one source of both the view's sums layout and the window's
  layout, so the two cannot disagree.
This module needs no device: settings, reports and tests read it without OpenCL.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .layout import Record

# A split candidate's sums over the pixels left of it (the right side is the pair's totals minus them), each
# over the pixels with a gradient: the unit vectors' x and y, their count, |g_x| and |g_y| (g in NDC units).
# Kernels index a candidate's lanes as SPLIT_<NAME>, SPLIT_WIDTH apart.
SPLIT_LANES = Record("SPLIT", [("ux", 1), ("uy", 1), ("count", 1), ("abs_x", 1), ("abs_y", 1)])
SPLIT_SUMS = SPLIT_LANES.width


@dataclass(frozen=True)
class SumsLayout:
    """Which sums the backward gathers: the gradients always, mean2d (2, px), conic (3), opacity (1), rgb (3);
    with stats: abs (2, sum |g_x|, |g_y| in NDC units), pixels (1); with dc_stats: dc (3, sum of g/|g| and
    the count: the SPLIT_LANES ux, uy, count over all the pixels); with split_candidates N: split
    (SPLIT_SUMS x N, the left side of each candidate)."""
    stats: bool = False
    dc_stats: bool = False
    split_candidates: int = 0

    def __post_init__(self):
        if self.dc_stats and not self.stats:
            raise ValueError("directional-consistency statistics need the base statistics")
        if self.split_candidates and not self.dc_stats:
            raise ValueError("split costs need the directional-consistency statistics")
        if self.split_candidates and self.split_candidates % 2 == 0:
            raise ValueError("the number of split candidates must be odd")

    @cached_property
    def record(self) -> Record:
        fields = [("mean2d", 2), ("conic", 3), ("opacity", 1), ("rgb", 3)]
        if self.stats:
            fields += [("abs", 2), ("pixels", 1)]
        if self.dc_stats:
            fields += [("dc", 3)]
        if self.split_candidates:
            fields += [("split", SPLIT_SUMS * self.split_candidates)]
        return Record("SUM", fields)

    @property
    def width(self) -> int:
        return self.record.width

    def defines(self) -> dict[str, int]:
        """The record's offsets and the kernels' switches (with split sums, the split lanes and the split
        geometry's offsets)."""
        split = ({**geometry_record(self.split_candidates).defines(), **SPLIT_LANES.defines()}
                 if self.split_candidates else {})
        return {**self.record.defines(), **split, "STATS": int(self.stats), "DC_STATS": int(self.dc_stats),
                "SPLIT_CANDIDATES": self.split_candidates}

    def views(self, sums: np.ndarray) -> dict[str, np.ndarray]:
        """(N, width) host rows -> named views."""
        return self.record.views(sums)


GRADIENTS = SumsLayout()   # the gradients alone: what a view gathers once the densification window has closed


def geometry_record(candidates: int) -> Record:
    """Per Gaussian, px: the first candidate's pixel (origin), the unit direction of the projected axis
    (dir; (0, 0): no split line in this view) and t_1 .. t_{N-1}, the other candidates' positions along it
    (t_0 = 0)."""
    return Record("GEO", [("origin", 2), ("dir", 2), ("t", candidates - 1)])


# Window columns. Base columns (every strategy); g = a pixel's dL/dmean2d in NDC units.
GRAD = "grad"               # |sum_j g_j| per view (3DGS)
ABS = "abs"                 # |(sum_j |g_x|, sum_j |g_y|)| per view (AbsGS' homodirectional gradient)
VIEWS = "views"             # views in which the Gaussian was visible
PIX_GRAD = "pix_grad"       # f |sum_j g_j| pix_v per view, f the depth factor (Pixel-GS)
PIX = "pix"                 # pixels where it was blended (Pixel-GS' count)
MAX_RADIUS = "max_radius"   # largest screen radius, px (the screen-size pruning rule)
BASE_COLUMNS = (GRAD, ABS, VIEWS, PIX_GRAD, PIX, MAX_RADIUS)

# DCC: (1 - kappa) times a base's per-view term, kappa the view's (or window's) directional consistency.
DCC_ABS, DCC_GRAD, DCC_PIX = "dcc_abs", "dcc_grad", "dcc_pix"
DC_WEIGHTED = {GRAD: DCC_GRAD, ABS: DCC_ABS, PIX_GRAD: DCC_PIX}   # a base's term -> its DC-weighted column
DC_WINDOW_COLUMNS = ("dc_ux", "dc_uy", "dc_n")   # window pooling: the unit-vector sums since the last step

# DCS: the candidates' split costs; with window pooling, the sides' running sums (SPLIT_LANES each).
SPLIT_COSTS = "split_costs"
SIDE_TOTAL, SIDE_LEFT = "side_total", "side_left"
# Non-zero withholds a Gaussian's split line (kernels/split_geometry.cl): DCS' tracking stops gathering split costs
# for Gaussians that cannot reach the split threshold.
SKIP_SPLIT = "skip_split"
NO_WINDOW = Record("WIN", [(SKIP_SPLIT, 1)])   # the split geometry without a window: every Gaussian tracked
# The window columns that hold a largest value or a flag, not a sum over the views: the windows of processes
# training together (train/parallel.py) combine by their maximum there, by their sum everywhere else
MAX_COLUMNS = (MAX_RADIUS, SKIP_SPLIT)

PIXELGS_DEPTH_FRACTION = 0.37   # Pixel-GS: gradients of Gaussians nearer than this x extent are scaled down
TRACK_MIN_VIEWS = 5             # DCS tracking: split costs for every Gaussian in its first views of a window


def mean_per_view(total: np.ndarray, count: np.ndarray) -> np.ndarray:
    """total / count, 0 where count is 0."""
    return np.where(count > 0, total / np.where(count > 0, count, 1), 0.0)


@dataclass(frozen=True)
class Criterion:
    """A densification criterion read from the window: column `total` over column `count`."""
    total: str
    count: str

    def __call__(self, window: dict[str, np.ndarray]) -> np.ndarray:
        return mean_per_view(window[self.total], window[self.count])


GRAD_PER_VIEW = Criterion(GRAD, VIEWS)        # 3DGS
ABS_PER_VIEW = Criterion(ABS, VIEWS)          # AbsGS' split criterion
GRAD_PER_PIXEL = Criterion(PIX_GRAD, PIX)     # Pixel-GS


@dataclass(frozen=True)
class StatisticsSpec:
    """What a strategy gathers while its window is open. dc: DC4GS' directional-consistency sums (DCC, and
    DCS needs them); split_candidates: DCS' split sums; window_pooling: kappa (and the split sides) pooled
    over the window rather than per view; tracked: the split criterion DCS tracking reads (TRACK_TOTAL,
    TRACK_COUNT), cost gathering stopping for a Gaussian whose criterion stays under the threshold;
    split_sums: whether the view gathers the split sums (False: a view DCS skips, DC4GSConfig.cost_every; the
    window, split costs included, keeps its layout, and the fold leaves the split costs as they are)."""
    dc: bool = False
    split_candidates: int = 0
    window_pooling: bool = False
    tracked: Criterion = GRAD_PER_VIEW
    split_sums: bool = True

    @cached_property
    def sums(self) -> SumsLayout:
        """The backward's per-Gaussian sums of one view (SumsLayout validates the combination)."""
        return SumsLayout(stats=True, dc_stats=self.dc,
                          split_candidates=self.split_candidates if self.split_sums else 0)

    @cached_property
    def window(self) -> Record:
        columns = [(name, 1) for name in BASE_COLUMNS]
        if self.dc:
            columns += [(name, 1) for name in (DCC_ABS, DCC_GRAD, DCC_PIX)]
            if self.window_pooling:
                columns += [(name, 1) for name in DC_WINDOW_COLUMNS]
        if self.split_candidates:
            columns += [(SPLIT_COSTS, self.split_candidates), (SKIP_SPLIT, 1)]
            if self.window_pooling:
                columns += [(SIDE_TOTAL, SPLIT_SUMS), (SIDE_LEFT, SPLIT_SUMS * self.split_candidates)]
        return Record("WIN", columns)

    def defines(self) -> dict[str, int]:
        """Everything the window's fold (kernels/window_fold.h) is built with, the view's sums layout included."""
        window = self.window
        return {**self.sums.defines(), **window.defines(),
                "DC_WINDOW": int(self.window_pooling), "TRACK_TOTAL": window.offsets[self.tracked.total],
                "TRACK_COUNT": window.offsets[self.tracked.count], "TRACK_MIN_VIEWS": TRACK_MIN_VIEWS}
