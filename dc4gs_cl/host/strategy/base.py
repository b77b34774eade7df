"""The densification strategy: when to densify, clone, split, prune and reset, and on which criterion.

A strategy keeps its hyperparameters apart from the trainer, which only calls its hooks (the shape of
gsplat's strategies). The 3DGS recipe is the base; AbsGS and Pixel-GS change the criterion and a few
numbers (../shared/docs/dc4gs-spec.md sections 3, 5 and 6).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...render.backward import SumsLayout
from .. import dc4gs, ops
from ..dc4gs import DC4GSConfig
from ..ops import GaussianSet
from ..stats import WindowLayout


@dataclass(frozen=True)
class DensifyConfig:
    densify_from: int = 500            # densify at iterations densify_from < it < densify_until ...
    densify_until: int = 15_000        # ... that are multiples of densify_every; statistics gather while it < this
    densify_every: int = 100
    clone_threshold: float = 2e-4      # on the mean per-view criterion, NDC units
    split_threshold: float = 2e-4
    percent_dense: float = 0.01        # "small" = largest scale <= percent_dense * extent: clone, else split
    prune_opacity: float = 0.005
    big_world_after: int = 3_000       # after this iteration also prune largest scale > big_world_fraction * extent
    big_world_fraction: float = 0.1
    screen_size_px: float | None = None  # the 3DGS screen-size rule (radius > 20 px); off: it never fires in the releases
    opacity_reset_every: int = 3_000
    opacity_reset_to: float = 0.01
    opacity_clamp_every: int | None = None   # AbsGS: clamp opacities to <= opacity_clamp this often
    opacity_clamp: float = 0.8


@dataclass
class DensifyReport:
    cloned: int = 0
    split: int = 0
    pruned: int = 0


def mean_per_view(total: np.ndarray, count: np.ndarray) -> np.ndarray:
    """total / count, 0 where count is 0."""
    return np.where(count > 0, total / np.where(count > 0, count, 1), 0.0)


class Strategy:
    """3DGS: clone small and split large Gaussians whose mean per-view |sum of NDC gradients| reaches
    the threshold; random split into two. With DC4GS, the split criterion becomes the DC-weighted one
    (DCC) and / or the split is placed by the directional-consistency costs (DCS)."""
    name = "3dgs"

    def __init__(self, config: DensifyConfig | None = None, dc4gs_config: DC4GSConfig | None = None):
        self.config = config or self.default_config()
        self.dc4gs = dc4gs_config

    @staticmethod
    def default_config() -> DensifyConfig:
        return DensifyConfig()

    @property
    def label(self) -> str:
        if self.dc4gs is None:
            return self.name
        parts = [p for p, on in (("DCC", self.dc4gs.dcc), ("DCS", self.dc4gs.dcs)) if on]
        return f"{self.name}+{'DC4GS' if len(parts) == 2 else parts[0]}"

    # what the device gathers ---------------------------------------------------------------------------
    @property
    def split_candidates(self) -> int:
        return self.dc4gs.candidates if self.dc4gs is not None and self.dc4gs.dcs else 0

    def sums_layout(self) -> SumsLayout:
        return SumsLayout(stats=True, dc_stats=self.dc4gs is not None, split_candidates=self.split_candidates)

    def window_layout(self) -> WindowLayout:
        return WindowLayout(dc=self.dc4gs is not None, split_candidates=self.split_candidates,
                            window_pooling=self.dc4gs is not None and self.dc4gs.pooling == "window",
                            criterion=self.criterion_columns())

    @property
    def track_threshold(self) -> float:
        """Split costs are gathered for a Gaussian while its running split criterion is at least this (and
        in its first views of a window): DC4GSConfig.track x the split threshold."""
        return self.dc4gs.track * self.config.split_threshold if self.dc4gs is not None else 0.0

    # schedule --------------------------------------------------------------------------------------
    def collecting(self, it: int) -> bool:
        """Whether iteration it gathers densification statistics."""
        return it < self.config.densify_until

    def densify_now(self, it: int) -> bool:
        c = self.config
        return c.densify_from < it < c.densify_until and it % c.densify_every == 0

    def reset_opacity_now(self, it: int, white_background: bool) -> bool:
        c = self.config
        return it < c.densify_until and (it % c.opacity_reset_every == 0
                                         or (white_background and it == c.densify_from))

    def clamp_opacity_now(self, it: int) -> bool:
        c = self.config
        return c.opacity_clamp_every is not None and it < c.densify_until and it % c.opacity_clamp_every == 0

    # criteria ----------------------------------------------------------------------------------------
    def clone_values(self, stats: dict[str, np.ndarray]) -> np.ndarray:
        return mean_per_view(stats["grad"], stats["views"])

    # The split criterion as window columns (total, count): its value is total / count.
    split_columns = ("grad", "views")
    dcc_base_columns = ("dcc_grad", "views")   # DCC weighting this base's own per-view term (the paper's reading)

    def criterion_columns(self) -> tuple[str, str]:
        if self.dc4gs is None or not self.dc4gs.dcc:
            return self.split_columns
        return self.dcc_base_columns if self.dc4gs.dcc_reading == "base" else ("dcc_abs", "views")

    def split_criterion(self, stats: dict[str, np.ndarray]) -> np.ndarray:
        total, count = self.criterion_columns()
        return mean_per_view(stats[total], stats[count])

    def split(self, gs: GaussianSet, mask: np.ndarray, rng: np.random.Generator, stats: dict[str, np.ndarray]) -> int:
        if not self.split_candidates:
            return ops.split_random(gs, mask, rng)
        idx = np.flatnonzero(mask)
        return dc4gs.split_at(gs, idx, dc4gs.split_positions(stats["j"][idx], self.dc4gs.split_pick))

    # the step ----------------------------------------------------------------------------------------
    def densify(self, gs: GaussianSet, stats: dict[str, np.ndarray], it: int, extent: float,
                rng: np.random.Generator) -> DensifyReport:
        """Clone, then split (clones are never split), then prune, as the 3DGS code orders them."""
        c = self.config
        n = gs.n
        clone_v, split_v = self.clone_values(stats), self.split_criterion(stats)
        gs.aux["max_radius"] = stats["max_radius"].astype(np.float32)
        large = gs.scales().max(axis=1) > c.percent_dense * extent
        report = DensifyReport()
        report.cloned = ops.clone(gs, (clone_v >= c.clone_threshold) & ~large)
        split_mask = np.zeros(gs.n, bool)
        split_mask[:n] = (split_v >= c.split_threshold) & large
        report.split = self.split(gs, split_mask, rng, stats)
        prune = gs.opacities() < c.prune_opacity
        if it > c.big_world_after:
            prune |= gs.scales().max(axis=1) > c.big_world_fraction * extent
        if c.screen_size_px is not None:
            prune |= gs.aux["max_radius"] > c.screen_size_px
        report.pruned = ops.prune(gs, prune)
        del gs.aux["max_radius"]
        return report
