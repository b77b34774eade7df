"""The densification strategy: when to densify, clone, split, prune and limit opacities, on which criterion,
and what the device must gather for it.

A strategy owns its hyperparameters (its own settings too: for_run), its statistics (the window on the device,
and DCS' split geometry stage), as gsplat's strategies do, its loss terms and its state in a checkpoint; the
trainer calls attach() once, then its hooks once per iteration, in this order:

    actions = strategy.actions(it)                        what this iteration does after its backward
    gathering = strategy.gather(it, params, cam, result)  what the rasterizer backward gathers this view, and
                                                          where it folds the view's statistics (plain data)
    ... rasterizer backward -> sums, the view folded into the window on the way ...
    ... optimiser step where actions say so, with the strategy's regularizers(n) ...
    strategy.after_step(it, params, lrs, seed)            after the optimiser step (MCMC's noise)
    report = strategy.apply(actions, it, model, rng)      densify and limit opacities; report

and around them checkpoint_state() / restore_state() (a checkpoint's window), reset(n) (a model started from)
and memory_held().

The 3DGS recipe is this base class; AbsGS and Pixel-GS change the criteria and a few numbers
(../shared/docs/dc4gs-spec.md sections 3, 5 and 6). DC4GS, on any base, makes the split criterion the
DC-weighted one (DCC) and / or places the split by the candidates' costs (DCS). A new base strategy is a
subclass that sets its name, criteria and default_config (tests/test_strategy.py adds one that way).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pyopencl as cl

from ..backward import SplitGeometry, WindowFold
from ..config import DC4GSConfig, DensifyConfig, TrainConfig
from ..model import GaussianSet
from ..render.gaussians import DeviceGaussians
from ..render.renderer import RenderResult
from ..render.stage import StageContext
from ..scene.camera import Camera
from ..statistics import GRAD_PER_VIEW, GRADIENTS, MAX_RADIUS, SPLIT_COSTS, Criterion, StatisticsSpec, SumsLayout
from . import ops
from .dc4gs import dcc_criterion, split_positions
from .ops import SPLIT_GROWTH
from .window import Window


@dataclass
class DensifyReport:
    cloned: int = 0
    split: int = 0
    pruned: int = 0
    capped: int = 0   # candidates left out by max_gaussians


@dataclass(frozen=True)
class Actions:
    """What an iteration does after its backward. 3DGS takes no optimiser step on a densification iteration
    (the Inria code densifies before its step, and new tensors have no gradient), unless step_with_densify (MCMC,
    as gsplat: the step, then the refinement), and no opacity step where the opacities are limited (the reset
    replaces them)."""
    densify: bool = False
    opacity_ceiling: float | None = None   # opacities above this drop to it (reset and / or clamp)
    step_with_densify: bool = False

    @property
    def optimiser_step(self) -> bool:
        return not self.densify or self.step_with_densify

    @property
    def opacity_steps(self) -> bool:
        return self.opacity_ceiling is None


@dataclass
class Gathering:
    """What the rasterizer backward gathers this view: the sums' layout, for DCS the view's split geometry, and
    where it folds the view's statistics (None once the window has closed)."""
    layout: SumsLayout
    geometry: cl.Buffer | None = None
    window: WindowFold | None = None


class Strategy:
    """3DGS: clone small and split large Gaussians whose mean per-view |sum of NDC gradients| reaches the
    threshold; random split into two."""
    name = "3dgs"
    initial: dict = {}   # how the initial Gaussians differ from model.from_points' defaults (its keyword arguments)
    scaled_interval = False   # whether a shorter run densifies more often (train/schedule.py says when)
    clone_criterion: Criterion = GRAD_PER_VIEW
    base_split_criterion: Criterion = GRAD_PER_VIEW   # the split criterion without DCC

    def __init__(self, config: DensifyConfig | None = None, dc4gs: DC4GSConfig | None = None):
        self.config = config or self.default_config()
        self.dc4gs = dc4gs if dc4gs is not None and dc4gs.enabled else None
        self.window: Window | None = None        # attach() makes the device state
        self.window_without_split: Window | None = None   # the views DCS skips fold with it (cost_every)
        self.split_geometry: SplitGeometry | None = None
        self.extent = 1.0
        self.white_background = False
        # an observer of the steps (a tool recording their decisions): densify calls it first, with (gs, window, it)
        self.before_densify: Callable[[GaussianSet, dict[str, np.ndarray], int], None] | None = None
        # the window over every process's views (train/parallel.py; the trainer sets it): identity for one process
        self.reduce_window: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] = lambda window: window

    @classmethod
    def for_run(cls, config: DensifyConfig, run: TrainConfig) -> Strategy:
        """The strategy of a run of these settings, config its densification settings (train/schedule.py scales
        them to the run); a strategy with settings of its own takes them from the run's here."""
        return cls(config, run.dc4gs)

    @staticmethod
    def default_config() -> DensifyConfig:
        return DensifyConfig()

    @property
    def label(self) -> str:
        return self.name if self.dc4gs is None else f"{self.name}+{self.dc4gs.label}"

    # criteria ------------------------------------------------------------------------------------------
    @property
    def split_criterion(self) -> Criterion:
        if self.dc4gs is None or not self.dc4gs.dcc:
            return self.base_split_criterion
        return dcc_criterion(self.base_split_criterion, self.dc4gs.dcc_reading)

    @property
    def split_candidates(self) -> int:
        """Candidate split positions whose costs the device gathers (0: none)."""
        return self.dc4gs.candidate_count if self.dc4gs is not None and self.dc4gs.costs_pick else 0

    @cached_property
    def statistics(self) -> StatisticsSpec:
        """What the device gathers while the window is open."""
        return StatisticsSpec(dc=self.dc4gs is not None, split_candidates=self.split_candidates,
                              window_pooling=self.dc4gs is not None and self.dc4gs.pooling == "window",
                              tracked=self.split_criterion)

    @property
    def track_threshold(self) -> float:
        """Split costs are gathered for a Gaussian while its running split criterion is at least this (and
        in its first views of a window): DC4GSConfig.track x the split threshold."""
        return self.dc4gs.track * self.config.split_threshold if self.dc4gs is not None else 0.0

    # schedule ----------------------------------------------------------------------------------------
    @property
    def last_densify_step(self) -> int:
        """The window's last densification step (0: none)."""
        c = self.config
        last = (c.densify_until - 1) // c.densify_every * c.densify_every
        return last if last > c.densify_from else 0

    def collecting(self, it: int) -> bool:
        """Whether iteration it gathers densification statistics: up to the window's last densification step.
        What the recipe gathers after it (14,901 to 14,999 of 30,000; 1,401 to 1,499 of 3,000) no step reads, so
        those iterations run the backward without statistics, DC4GS' split costs included."""
        return it <= self.last_densify_step

    def densify_now(self, it: int) -> bool:
        c = self.config
        return c.densify_from < it < c.densify_until and it % c.densify_every == 0

    def reset_opacity_now(self, it: int, white_background: bool) -> bool:
        c = self.config
        return it < c.densify_until and (c.opacity_reset_every > 0 and it % c.opacity_reset_every == 0
                                         or (white_background and it == c.densify_from))

    def clamp_opacity_now(self, it: int) -> bool:
        c = self.config
        return c.opacity_clamp_every is not None and it < c.densify_until and it % c.opacity_clamp_every == 0

    def actions(self, it: int) -> Actions:
        c = self.config
        ceilings = [ceiling for ceiling, now in ((c.opacity_clamp, self.clamp_opacity_now(it)),
                                                 (c.opacity_reset_to,
                                                  self.reset_opacity_now(it, self.white_background)))
                    if now]
        return Actions(densify=self.densify_now(it), opacity_ceiling=min(ceilings) if ceilings else None)

    # device hooks ----------------------------------------------------------------------------------------
    def attach(self, ctx: StageContext, extent: float, n: int, white_background: bool = False) -> None:
        """Make the device state for a scene of this extent and n Gaussians: the window and, for DCS, the
        split geometry stage (sharing the trainer's stage context)."""
        self.extent, self.white_background = extent, white_background
        self.window = Window(ctx.rt, self.statistics, extent, self.track_threshold)
        self.window.reset(n)
        self.split_geometry = SplitGeometry(ctx) if self.split_candidates else None
        # DCS gathering split costs from every K-th view only: the others fold through this
        self.window_without_split = (self.window.without_split_sums()
                                     if self.split_candidates and self.dc4gs.cost_every > 1 else None)

    def gather(self, it: int, params: DeviceGaussians, cam: Camera, res: RenderResult) -> Gathering:
        """What the backward gathers this view: the gradients alone once the window has closed; otherwise the
        window's statistics and, for DCS, the split geometry of the Gaussians that can be split (largest scale
        above percent_dense x extent) and that the window still tracks (where this view adds to the split costs)."""
        if not self.collecting(it):
            return Gathering(GRADIENTS)
        if self.window_without_split is not None and it % self.dc4gs.cost_every:   # a view DCS skips
            return Gathering(self.window_without_split.spec.sums, None, self.window_without_split.fold)
        fold = self.window.fold
        geometry = None
        if self.split_geometry is not None:
            geometry = self.split_geometry(params, cam, res, self.split_candidates,
                                           self.config.percent_dense * self.extent, fold)
        return Gathering(self.statistics.sums, geometry, fold)

    def regularizers(self, n: int) -> tuple[float, float] | None:
        """The strategy's loss terms on n Gaussians' opacities and scales, as the gradient factors the optimiser
        step takes (per Gaussian and per scale value: project_backward.cl, REGULARIZED); None: none (MCMC's)."""
        return None

    def after_step(self, it: int, params: DeviceGaussians, lrs: dict, seed: int) -> None:
        """Queued after iteration it's optimiser step (lrs: its learning rates; seed: the run's): nothing here
        (MCMC's noise)."""

    def apply(self, actions: Actions, it: int, model, rng: np.random.Generator) -> DensifyReport | None:
        """Densify (on the device model: optim.trainable.TrainableGaussians) and limit the opacities as the
        actions say; the report of a densification step, else None."""
        report = None
        if actions.densify:
            gs = model.download()
            report = self.densify(gs, self.reduce_window(self.window.download()), it, rng)
            model.upload(gs)
            self.reset(gs.n)
        if actions.opacity_ceiling is not None:
            model.limit_opacity(actions.opacity_ceiling)
        return report

    def reset(self, n: int) -> None:
        """Restart the window, for n Gaussians (after a densification step, or for a model the trainer starts
        from)."""
        self.window.reset(n)

    def memory_held(self) -> dict[str, int]:
        """Device bytes the strategy holds, by what holds them."""
        return {"window statistics": self.window.rows.nbytes}

    # state in a checkpoint -------------------------------------------------------------------------------
    def checkpoint_state(self) -> dict[str, np.ndarray]:
        """What a checkpoint holds of the strategy: its window's columns over every process's views
        (reduce_window; in a parallel run every process calls this together)."""
        return self.reduce_window(self.window.download())

    def restore_state(self, state: dict[str, np.ndarray], holder: bool = True) -> None:
        """Continue from a checkpoint_state. In a parallel run only the holder (process 0) takes it, the others'
        windows restarting at zero, so that the processes' windows still reduce to it."""
        self.window.upload(state if holder else {k: np.zeros_like(v) for k, v in state.items()})

    # the step --------------------------------------------------------------------------------------------
    def split(self, gs: GaussianSet, mask: np.ndarray, rng: np.random.Generator, window: dict[str, np.ndarray]) -> int:
        if self.dc4gs is None or not self.dc4gs.dcs:
            return ops.split_random(gs, mask, rng)
        idx = np.flatnonzero(mask)
        return ops.split_at(gs, idx, self.dcs_cuts(window, idx), self.dc4gs.other_scale)

    def dcs_cuts(self, window: dict[str, np.ndarray], idx: np.ndarray) -> np.ndarray:
        """Where DCS cuts the Gaussians idx along their principal axes, in (0, 1): where their split costs are
        lowest, or the middle with split_pick middle (no costs gathered)."""
        if not self.split_candidates:
            return np.full(len(idx), 0.5)
        return split_positions(window[SPLIT_COSTS][idx], self.dc4gs.split_pick)

    def large(self, gs: GaussianSet) -> np.ndarray:
        """The Gaussians a step would split rather than clone: largest scale above percent_dense x extent."""
        return gs.scales().max(axis=1) > self.config.percent_dense * self.extent

    def densify(self, gs: GaussianSet, window: dict[str, np.ndarray], it: int,
                rng: np.random.Generator) -> DensifyReport:
        """Clone, then split (clones are never split), then prune, as the 3DGS code orders them."""
        if self.before_densify is not None:
            self.before_densify(gs, window, it)
        c = self.config
        n = gs.n
        clone_v, split_v = self.clone_criterion(window), self.split_criterion(window)
        gs.aux[MAX_RADIUS] = window[MAX_RADIUS].astype(np.float32)
        large = self.large(gs)
        report = DensifyReport()
        clone_mask = (clone_v >= c.clone_threshold) & ~large
        split_mask = (split_v >= c.split_threshold) & large
        if c.max_gaussians is not None:
            wanted = int(clone_mask.sum() + split_mask.sum())
            clone_mask, split_mask = ops.cap_growth(c.max_gaussians - n, [
                (clone_mask, clone_v / c.clone_threshold, 1), (split_mask, split_v / c.split_threshold, SPLIT_GROWTH)])
            report.capped = wanted - int(clone_mask.sum() + split_mask.sum())
        report.cloned = ops.clone(gs, clone_mask)
        report.split = self.split(gs, np.concatenate([split_mask, np.zeros(gs.n - n, bool)]), rng, window)
        prune = gs.opacities() < c.prune_opacity
        if it > c.big_world_after:
            prune |= gs.scales().max(axis=1) > c.big_world_fraction * self.extent
        if c.screen_size_px is not None:
            prune |= gs.aux[MAX_RADIUS] > c.screen_size_px
        report.pruned = ops.prune(gs, prune)
        del gs.aux[MAX_RADIUS]
        return report
