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

# Workspace buffers of a view walked in runs of tiles (render/workspace.py)
RUN_ENDS = "backward.run_ends"             # [runs] uint: each run's end pair
RUN_SPANS = "backward.run_spans"           # [N] uint: each Gaussian's first and last run, 16 bits each
SPANNING = "backward.spanning"             # [1] uint: how many Gaussians have pairs in more than one run
RUN_MEMBERS = "backward.run_members"       # [N] uint: the Gaussians with a pair in one run
RUN_COUNT = "backward.run_count"           # [1] uint: how many
CARRY_SLOT = "backward.carry_slot"         # Carry's buffers
CARRY_TAKEN = "backward.carry_taken"
CARRY_ROWS = "backward.carry_rows"


class Carry(NamedTuple):
    """Where a view walked in runs of tiles keeps the partial sums of the Gaussians whose pairs span runs, while
    sum_pairs folds the window (kernels/sum_pairs.cl): each one's row, the rows taken, the rows."""
    slot: cl.Buffer      # [N] uint
    taken: cl.Buffer     # [1] uint, zeroed for each view
    rows: cl.Buffer      # [rows * SUM_WIDTH] float


class Members(NamedTuple):
    """The Gaussians with a pair in one run of tiles (past the first) of a view walked in runs: sum_pairs covers
    these alone, where each run would otherwise look at every Gaussian (kernels/sum_pairs.cl, run_members)."""
    ids: cl.Buffer       # [count] uint
    count: cl.Buffer     # [1] uint, on the device (sum_pairs reads it there)


class SumPairs(Stage):
    FILE, KERNELS = "sum_pairs.cl", ("sum_pairs", "run_spans", "run_members")

    def variant(self, layout: SumsLayout, window: WindowFold | None) -> dict[str, cl.Kernel]:
        """The kernels that sum these sums and fold them into this window (None: no fold)."""
        fold = {"FOLD_WINDOW": int(window is not None), "GRADIENT_WIDTH": GRADIENTS.width,
                **(window.defines if window is not None else {})}
        return self.kernels({**layout.defines(), **fold})

    def run_spans(self, res: RenderResult, layout: SumsLayout, window: WindowFold | None, runs: list[tuple]) -> int:
        """Each Gaussian's first and last run of these runs of tiles (backward.rasterize_backward.tile_runs), kept
        on the device for members(); how many Gaussians have pairs in more than one run (read back). (layout and
        window: the variant whose program holds the kernel.)"""
        rt, n = self.rt, res.proj.n
        if len(runs) >= 1 << 16:
            raise ValueError(f"{len(runs)} runs of tiles: a Gaussian's runs are kept in 16 bits each")
        spanning = self.ws.get(SPANNING, 4)
        run_ends = self.ws.get(RUN_ENDS, 4 * len(runs))
        rt.write_async(run_ends, np.array([r[3] for r in runs], np.uint32))
        rt.fill(spanning, np.uint32(0), 4)
        rt.launch_items("sum_pairs", self.variant(layout, window)["run_spans"], n, PER_GAUSSIAN_WG, self.ctx.frame,
                        np.uint32(n),
                        np.uint32(len(runs)), run_ends, res.proj.tiles_touched, res.isect.pair_first,
                        res.isect.pair_of_emission, self.ws.get(RUN_SPANS, 4 * max(n, 1)), spanning)
        return int(rt.to_host(spanning, 1, np.uint32)[0])

    def members(self, res: RenderResult, layout: SumsLayout, window: WindowFold | None, run: int) -> Members:
        """The Gaussians with a pair in run `run`, from the last run_spans (listed and counted on the device)."""
        rt, n = self.rt, res.proj.n
        ids, count = self.ws.get(RUN_MEMBERS, 4 * max(n, 1)), self.ws.get(RUN_COUNT, 4)
        rt.fill(count, np.uint32(0), 4)
        rt.launch_items("sum_pairs", self.variant(layout, window)["run_members"], n, PER_GAUSSIAN_WG, self.ctx.frame,
                        np.uint32(n),
                        np.uint32(run), self.ws.get(RUN_SPANS, 4 * max(n, 1)), ids, count)
        return Members(ids, count)

    def carry(self, layout: SumsLayout, n: int, spanning: int) -> Carry:
        """The carry of a view walked in runs of tiles, with a row for each of the `spanning` Gaussians whose pairs
        span runs (run_spans), none taken yet; with none (one run), sum_pairs touches no carry."""
        taken = self.ws.get(CARRY_TAKEN, 4)
        if not spanning:
            return Carry(taken, taken, taken)
        self.rt.fill(taken, np.uint32(0), 4)
        return Carry(self.ws.get(CARRY_SLOT, 4 * max(n, 1)), taken, self.ws.get(CARRY_ROWS, 4 * layout.width * spanning))

    def __call__(self, res: RenderResult, layout: SumsLayout, pair_sums: cl.Buffer, pair0: int, pair_end: int,
                 split_geometry: cl.Buffer, sums: cl.Buffer, window: WindowFold | None = None,
                 carry: Carry | None = None, members: Members | None = None) -> None:
        """Add the slots of pairs pair0 .. pair_end - 1 onto sums (N x layout.width; written, not added to, when
        pair0 is 0), for the Gaussians of `members` only where given (a run past the first). window (with the
        view's carry): fold the view into it, each Gaussian in the run holding its last pair; sums are then
        N x GRADIENTS.width."""
        n = res.proj.n
        if n:
            folding = [*window.args(res), window.rows, *carry] if window is not None else []
            listed = [np.int32(1), members.count, members.ids] if members is not None else [np.int32(0), sums, sums]
            self.rt.launch_items("sum_pairs", self.variant(layout, window)["sum_pairs"], n, PER_GAUSSIAN_WG,
                                 self.ctx.frame, np.uint32(n), np.uint32(pair0), np.uint32(pair_end),
                                 np.int32(pair0 > 0), *listed, res.proj.tiles_touched, res.isect.pair_first,
                                 res.isect.pair_of_emission, pair_sums,
                                 split_geometry, *folding, sums)
        if window is not None and pair_end == res.isect.pair_bound:
            self.check(lambda: window.download(self.rt, n))
