"""What density control gathers on the device, described once.

The densification window (kernels/densify_stats.cl) holds per Gaussian a row of columns, summed over the
views in which it was visible since the last densification step; the names below are the only spelling
of those columns on the host (the kernel reads them as WIN_<NAME>). A strategy reads the window through
Criterion values built from these names. A StatisticsSpec, made by the strategy, is the one source of both
the backward's sums layout (what each view gathers) and the window's layout, so the two cannot disagree.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ...backward import SumsLayout
from ...backward.sums import SPLIT_SUMS
from ...backward.split_geometry import SKIP_SPLIT
from ...layout import Record

# Base columns (every strategy); g = a pixel's dL/dmean2d in NDC units.
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

# DCS: the candidates' split costs; with window pooling, the sides' running sums.
SPLIT_COSTS = "split_costs"
SIDE_TOTAL, SIDE_LEFT = "side_total", "side_left"   # SPLIT_SUMS per side: u_x, u_y, count, |g_x|, |g_y|

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
        return SumsLayout(stats=True, dc_stats=self.dc, split_candidates=self.split_candidates if self.split_sums else 0)

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
        """Everything kernels/densify_stats.cl is built with."""
        window = self.window
        return {**self.sums.defines(), **window.defines(),
                "DC_WINDOW": int(self.window_pooling), "TRACK_TOTAL": window.offsets[self.tracked.total],
                "TRACK_COUNT": window.offsets[self.tracked.count], "TRACK_MIN_VIEWS": TRACK_MIN_VIEWS}
