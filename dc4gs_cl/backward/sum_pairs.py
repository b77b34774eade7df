"""Pair-sums stage (kernels/sum_pairs.cl): the rasterizer backward's per-pair slots added up per Gaussian in a
fixed order, and, when a densification window is given, that view's statistics folded into the window on the
way (kernels/window_fold.h), so the per-Gaussian sums that reach memory are the gradients alone."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pyopencl as cl

from ..render.renderer import RenderResult
from ..render.stage import PER_GAUSSIAN_WG, Stage
from ..statistics import GRADIENTS, SumsLayout
from .densify_stats import WindowFold

# Workspace buffers of a view walked in runs (render/workspace.py)
RUN_SPANS = "backward.run_spans"           # [N] uint: each Gaussian's first and last run, 16 bits each
CARRY_SLOT = "backward.carry_slot"         # Carry's buffers
CARRY_TAKEN = "backward.carry_taken"
CARRY_ROWS = "backward.carry_rows"
NO_ROW_LIMIT = 0xFFFFFFFF                  # run_spans' carry_rows where none is to be checked


class Carry(NamedTuple):
    """Where a view walked in runs keeps the partial sums of the Gaussians whose pairs span runs, while sum_pairs
    folds the window (kernels/sum_pairs.cl): each one's row, the rows taken, the rows."""
    slot: cl.Buffer      # [N] uint
    taken: cl.Buffer     # [1] uint, zeroed for each view
    rows: cl.Buffer      # [rows * SUM_WIDTH] float


class SumPairs(Stage):
    FILE, KERNELS = "sum_pairs.cl", ("sum_pairs", "run_spans")

    def variant(self, layout: SumsLayout, window: WindowFold | None) -> dict[str, cl.Kernel]:
        """The kernels that sum these sums and fold them into this window (None: no fold)."""
        fold = {"FOLD_WINDOW": int(window is not None), "GRADIENT_WIDTH": GRADIENTS.width,
                **(window.defines if window is not None else {})}
        return self.kernels({**layout.defines(), **fold})

    def run_spans(self, res: RenderResult, layout: SumsLayout, window: WindowFold | None, pairs_per_run: int,
                  runs: int, carry_rows: int | None) -> None:
        """Each Gaussian's first and last run of a view walked in `runs` runs of pairs_per_run pairs, kept on the
        device for sum_pairs, and how many Gaussians have pairs in more than one run in the frame's SPANNING word;
        more than carry_rows of them (None: no limit) make the frame void. (layout and window: the variant whose
        program holds the kernel.)"""
        if runs >= 1 << 16:
            raise ValueError(f"{runs} runs: a Gaussian's runs are kept in 16 bits each")
        n = res.proj.n
        self.rt.launch_items("sum_pairs", self.variant(layout, window)["run_spans"], n, PER_GAUSSIAN_WG,
                             self.ctx.frame, np.uint32(n), np.uint32(pairs_per_run),
                             np.uint32(NO_ROW_LIMIT if carry_rows is None else carry_rows), res.proj.tiles_touched,
                             res.isect.pair_first, res.isect.pair_of_emission, self.ws.get(RUN_SPANS, 4 * max(n, 1)))

    def carry(self, layout: SumsLayout, n: int, rows: int) -> Carry:
        """The carry of a view walked in runs, with `rows` rows (for as many Gaussians spanning runs), none taken
        yet; with none, sum_pairs touches no carry."""
        taken = self.ws.get(CARRY_TAKEN, 4)
        if not rows:
            return Carry(taken, taken, taken)
        self.rt.fill(taken, np.uint32(0), 4)
        return Carry(self.ws.get(CARRY_SLOT, 4 * max(n, 1)), taken, self.ws.get(CARRY_ROWS, 4 * layout.width * rows))

    def __call__(self, res: RenderResult, layout: SumsLayout, pair_sums: cl.Buffer, pair0: int, pair_end: int,
                 run: int, runs: int, split_geometry: cl.Buffer, sums: cl.Buffer, window: WindowFold | None = None,
                 carry: Carry | None = None) -> None:
        """Add the slots of pairs pair0 .. pair_end - 1, run `run` of `runs` (each Gaussian's runs from the last
        run_spans where there are several), onto sums (N x layout.width; written for every Gaussian in run 0).
        window (with the view's carry): fold the view into it, each Gaussian in its last run; sums are then
        N x GRADIENTS.width."""
        n = res.proj.n
        if n:
            folding = [*window.args(res), window.rows, *carry] if window is not None else []
            spans = self.ws.get(RUN_SPANS, 4 * max(n, 1)) if runs > 1 else sums
            self.rt.launch_items("sum_pairs", self.variant(layout, window)["sum_pairs"], n, PER_GAUSSIAN_WG,
                                 self.ctx.frame, np.uint32(n), np.uint32(pair0), np.uint32(pair_end), np.uint32(run),
                                 np.int32(runs > 1), spans, res.proj.tiles_touched, res.isect.pair_first,
                                 res.isect.pair_of_emission, pair_sums, split_geometry, *folding, sums)
        if window is not None and run == runs - 1:
            self.check(lambda: window.download(self.rt, n))
