"""MCMC densification (Kheradmand et al., "3D Gaussian Splatting as Markov Chain Monte Carlo", NeurIPS 2024), as
gsplat's MCMCStrategy runs it: no gradient statistics, no clone, split or opacity reset. At each refinement step
(every densify_every iterations inside the window; a shorter run's steps come as often relative to its length,
as gsplat's steps_scaler makes them) the dead Gaussians (opacity <= prune_opacity) are relocated
onto live ones drawn by opacity, then the model grows by GROWTH_RATE up to the cap (--max-gaussians, else
MCMC_DEFAULT_CAP), new ones again drawn by opacity; a Gaussian drawn N - 1 times shares its opacity and scale with
its N - 1 copies by the paper's equation (9) (relocated_opacity_scale). Every iteration, after Adam's step, the
positions get noise (optim/position_noise.py, the SGLD step), and the loss carries the regularisers
opacity_reg mean(opacity) + scale_reg mean(scale) (project_backward.cl, REGULARIZED); their rates are MCMC's own
settings (config.MCMCConfig).

With DCS (--strategy mcmc --dcs; DC4GS' split placement, our addition) the window gathers every Gaussian's split
costs, and a Gaussian drawn exactly once in a step becomes, with its copy, DCS' two children (cut where its costs
are lowest) rather than two coinciding halves; one drawn more often shares by equation (9) as without it.

Where this departs from gsplat: the Adam moments of a relocated Gaussian (the dead one's slot) restart at zero as
those of the live one it copies do (gsplat zeroes the live one's only); the draws come from the run's generator.
"""
from __future__ import annotations

import math

import numpy as np

from ..config import MCMC_DEFAULT_CAP, DC4GSConfig, DensifyConfig, MCMCConfig, TrainConfig
from ..model import GaussianSet, logit
from ..optim.position_noise import PositionNoise
from ..render.gaussians import DeviceGaussians
from .ops import split_children
from .strategy import Actions, DensifyReport, Strategy

GROWTH_RATE = 0.05       # each refinement step grows the model by 5% (up to the cap)
MAX_SHARES = 51          # the binomial formula's largest N (gsplat's n_max): a Gaussian drawn more often keeps this
INIT_OPACITY = 0.5       # the initial Gaussians' opacity and scale factor (gsplat's MCMC config: init_opa, init_scale)
INIT_SCALE_FACTOR = 0.1
OPACITY_EPS = float(np.finfo(np.float32).eps)   # new opacities stay below 1 - this


def relocated_opacity_scale(opacity: np.ndarray, scale: np.ndarray,
                            shares: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's equation (9): N Gaussians taking the place of one of opacity o and scale s (N = shares, at most
    MAX_SHARES) each get opacity 1 - (1 - o)^(1/N) and scale o / D s, with
    D = sum_{i=1..N} sum_{k=0..i-1} C(i-1, k) (-1)^k o_new^(k+1) / sqrt(k+1), so that together they render as it
    did. opacity (M,), scale (M, 3), shares (M,) ints >= 1; float64."""
    o = np.asarray(opacity, np.float64)
    n = np.minimum(np.asarray(shares), MAX_SHARES)
    new = 1 - (1 - o) ** (1 / n)
    denom = np.zeros_like(o)
    for i in range(1, MAX_SHARES + 1):
        active = n >= i
        if not active.any():
            break
        for k in range(i):
            denom += np.where(active, math.comb(i - 1, k) * (-1) ** k * new ** (k + 1) / math.sqrt(k + 1), 0.0)
    return new, (o / denom)[:, None] * np.asarray(scale, np.float64)


class MCMC(Strategy):
    name = "mcmc"
    initial = {"opacity": INIT_OPACITY, "scale_factor": INIT_SCALE_FACTOR}
    scaled_interval = True

    def __init__(self, config: DensifyConfig | None = None, dc4gs: DC4GSConfig | None = None,
                 settings: MCMCConfig | None = None):
        super().__init__(config, dc4gs)
        self.settings = settings or MCMCConfig()

    @classmethod
    def for_run(cls, config: DensifyConfig, run: TrainConfig) -> MCMC:
        return cls(config, run.dc4gs, run.mcmc)

    @staticmethod
    def default_config() -> DensifyConfig:
        # refine from 500 to 25,000 of 30,000 every 100; dead below opacity 0.005; no opacity resets; with DCS,
        # every Gaussian may be placed, so every one gathers split costs (percent_dense 0: no size rule)
        return DensifyConfig(densify_from=500, densify_until=25_000, densify_every=100, prune_opacity=0.005,
                             opacity_reset_every=0, percent_dense=0.0, max_gaussians=MCMC_DEFAULT_CAP)

    def collecting(self, it: int) -> bool:
        return self.dc4gs is not None and it <= self.last_densify_step   # DCS' split costs; else nothing

    def actions(self, it: int) -> Actions:
        return Actions(densify=self.densify_now(it), step_with_densify=True)

    def attach(self, ctx, extent: float, n: int, white_background: bool = False) -> None:
        super().attach(ctx, extent, n, white_background)
        self.noise = PositionNoise(ctx)

    def regularizers(self, n: int) -> tuple[float, float]:
        """opacity_reg mean(opacity) + scale_reg mean(scale)."""
        return self.settings.opacity_reg / n, self.settings.scale_reg / (3 * n)

    def after_step(self, it: int, params: DeviceGaussians, lrs: dict, seed: int) -> None:
        """The position noise of iteration it, after Adam's step (lrs: its learning rates)."""
        self.noise(params, it, seed, lrs["means"] * self.settings.noise_lr)

    def densify(self, gs: GaussianSet, window: dict[str, np.ndarray], it: int,
                rng: np.random.Generator) -> DensifyReport:
        """Relocate the dead, then grow by GROWTH_RATE up to the cap."""
        if self.before_densify is not None:
            self.before_densify(gs, window, it)
        c = self.config
        report = DensifyReport()
        # DCS: the Gaussians it may place, those whose split costs the window gathered and no share has touched yet
        placeable = np.ones(gs.n, bool) if self.dc4gs is not None else None
        opacity = gs.opacities()
        dead = np.flatnonzero(opacity <= c.prune_opacity)
        alive = np.flatnonzero(opacity > c.prune_opacity)
        if len(dead) and len(alive):
            report.pruned = self._share(gs, rng.choice(alive, len(dead), p=_weights(opacity[alive])), dead, window,
                                        placeable)
        cap = c.max_gaussians if c.max_gaussians is not None else gs.n
        grow = max(0, min(cap, int((1 + GROWTH_RATE) * gs.n)) - gs.n)
        if grow:
            report.cloned = self._share(gs, rng.choice(gs.n, grow, p=_weights(gs.opacities())), None, window,
                                        placeable)
        return report

    def _share(self, gs: GaussianSet, sampled: np.ndarray, into: np.ndarray | None, window: dict[str, np.ndarray],
               placeable: np.ndarray | None) -> int:
        """Each sampled Gaussian shares its opacity and scale with its copies, written over `into` (relocation)
        or appended (growth); the sampled and their copies restart Adam's moments. With DCS (placeable: a mask
        over the Gaussians before this step, see densify) a placeable Gaussian drawn once becomes, with its copy,
        DCS' two children instead: cut across its principal axis where its split costs are lowest (as DCS splits on
        the bases), not two copies on one spot."""
        counts = np.bincount(sampled, minlength=gs.n)
        opacity, scale = relocated_opacity_scale(gs.opacities()[sampled], gs.scales()[sampled], counts[sampled] + 1)
        opacity = np.clip(opacity, self.config.prune_opacity, 1 - OPACITY_EPS)
        if placeable is not None:
            once = np.flatnonzero((counts[sampled] == 1) & placeable[sampled])
            parents = sampled[once]
            children = split_children({k: v[parents] for k, v in gs.params.items()}, self.dcs_cuts(window, parents),
                                      self.dc4gs.other_scale)
        gs.params["opacity_logits"][sampled] = logit(opacity)[:, None].astype(np.float32)
        gs.params["log_scales"][sampled] = np.log(scale).astype(np.float32)
        for moments in (gs.m, gs.v):
            for array in moments.values():
                array[sampled] = 0
        if into is None:
            into = np.arange(gs.n, gs.n + len(sampled))
            gs.append({k: v[sampled] for k, v in gs.params.items()}, sampled)
        else:
            for k, v in gs.params.items():
                v[into] = v[sampled]
            for moments in (gs.m, gs.v):
                for array in moments.values():
                    array[into] = 0
        if placeable is not None:
            for k, v in gs.params.items():
                v[parents] = children[0][k]
                v[into[once]] = children[1][k]
            placeable[sampled] = False
            placeable[into[into < len(placeable)]] = False
        return len(sampled)


def _weights(opacity: np.ndarray) -> np.ndarray:
    """Draw probabilities proportional to opacity (gsplat's torch.multinomial on them)."""
    p = np.asarray(opacity, np.float64)
    return p / p.sum()

