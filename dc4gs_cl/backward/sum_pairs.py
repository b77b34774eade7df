"""Pair-sums stage (kernels/sum_pairs.cl): the rasterizer backward's per-pair slots added up per Gaussian in a
fixed order, and, when a densification window is given, that view's statistics folded into the window on the
way (kernels/window_fold.h), so the per-Gaussian sums that reach memory are the gradients alone."""
from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np
import pyopencl as cl

from ..render.renderer import RenderResult
from ..render.stage import PER_GAUSSIAN_WG, Stage
from .sums import GRADIENTS, SumsLayout


class WindowFold(Protocol):
    """A densification window (host/densify/densify_stats.py) as the backward sees it: what its fold kernel is
    built with, the arguments it takes for a view, and its own fold of a view's sums."""

    buffer: cl.Buffer   # the window's rows

    def defines(self) -> dict: ...

    def fold_args(self, res: RenderResult) -> list: ...

    def fold(self, res: RenderResult, sums: cl.Buffer, split_geometry: cl.Buffer | None = None) -> None: ...

    def folded(self) -> None: ...


class Carry(NamedTuple):
    """Where a view walked in runs of tiles keeps the partial sums of the Gaussians whose pairs span runs, while
    sum_pairs folds the window (kernels/sum_pairs.cl): each one's row, the rows taken, the rows."""
    slot: cl.Buffer      # [N] uint
    taken: cl.Buffer     # [1] uint, zeroed for each view
    rows: cl.Buffer      # [rows * SUM_WIDTH] float


class SumPairs(Stage):
    FILE, KERNELS = "sum_pairs.cl", ("sum_pairs", "count_spanning")

    def variant(self, layout: SumsLayout, window: WindowFold | None) -> dict[str, cl.Kernel]:
        """The kernels that sum these sums and fold them into this window (None: no fold)."""
        fold = {"FOLD_WINDOW": int(window is not None), "GRADIENT_WIDTH": GRADIENTS.width,
                **(window.defines() if window is not None else {})}
        return self.kernels({**layout.defines(), **fold})

    def count_spanning(self, res: RenderResult, layout: SumsLayout, window: WindowFold, runs: list[tuple]) -> int:
        """How many Gaussians have pairs in more than one of these runs of tiles (counted on the device, read back)."""
        rt, n = self.rt, res.proj.n
        spanning = self.ws.get("backward.carry_taken", 4)
        run_ends = self.ws.get("backward.run_ends", 4 * len(runs))
        rt.write(run_ends, np.array([r[3] for r in runs], np.uint32))
        rt.fill(spanning, np.uint32(0), 4)
        rt.launch_items("sum_pairs", self.variant(layout, window)["count_spanning"], n, PER_GAUSSIAN_WG,
                        np.uint32(n), np.uint32(len(runs)), run_ends, res.proj.tiles_touched, res.isect.pair_first,
                        res.isect.pair_of_emission, spanning)
        return int(rt.to_host(spanning, 1, np.uint32)[0])

    def carry(self, res: RenderResult, layout: SumsLayout, window: WindowFold, runs: list[tuple]) -> Carry:
        """The carry of a view walked in these runs of tiles (backward.rasterize_backward.tile_runs), with a row
        for each Gaussian whose pairs span runs; one run needs none."""
        n = res.proj.n
        taken = self.ws.get("backward.carry_taken", 4)
        if len(runs) == 1 or not n:
            return Carry(taken, taken, taken)
        rows = self.count_spanning(res, layout, window, runs)
        self.rt.fill(taken, np.uint32(0), 4)
        return Carry(self.ws.get("backward.carry_slot", 4 * n), taken,
                     self.ws.get("backward.carry_rows", 4 * layout.width * max(rows, 1)))

    def __call__(self, res: RenderResult, layout: SumsLayout, pair_sums: cl.Buffer, pair0: int, pair_end: int,
                 split_geometry: cl.Buffer, sums: cl.Buffer, window: WindowFold | None = None,
                 carry: Carry | None = None) -> None:
        """Add the slots of pairs pair0 .. pair_end - 1 onto sums (N x layout.width; written, not added to, when
        pair0 is 0). window (with the view's carry): fold the view into it, each Gaussian in the run holding its
        last pair; sums are then N x GRADIENTS.width."""
        n = res.proj.n
        if not n:
            return
        folding = [*window.fold_args(res), window.buffer, *carry] if window is not None else []
        self.rt.launch_items("sum_pairs", self.variant(layout, window)["sum_pairs"], n, PER_GAUSSIAN_WG,
                             np.uint32(n), np.uint32(pair0), np.uint32(pair_end), np.int32(pair0 > 0),
                             res.proj.tiles_touched, res.isect.pair_first, res.isect.pair_of_emission, pair_sums,
                             split_geometry, *folding, sums)
        if window is not None and pair_end == res.isect.n_pairs:
            window.folded()
