"""MCMC's position noise (kernels/position_noise.cl): once an iteration after Adam's step, each Gaussian's mean moves
by its covariance times standard normals, gated to the nearly transparent ones; the normals come from a counter-
based generator keyed by the run's seed and counted by the iteration, so a run resumed or a view run again draws
the same. Its float64 reference is reference/mcmc.py."""
from __future__ import annotations

import numpy as np

from ..constants import MCMC_NOISE_K, MCMC_NOISE_X0
from ..render.gaussians import DeviceGaussians
from ..render.stage import PER_GAUSSIAN_WG, Stage


def seed_words(seed: int) -> tuple[int, int]:
    """The Philox key of a run's seed (0 .. 2^63 - 1): its low and high 32 bits."""
    return seed & 0xFFFFFFFF, (seed >> 32) & 0xFFFFFFFF


class PositionNoise(Stage):
    FILE, KERNELS = "position_noise.cl", ("position_noise",)

    def defines(self) -> dict:
        return {"NOISE_K": MCMC_NOISE_K, "NOISE_X0": MCMC_NOISE_X0}

    def __call__(self, g: DeviceGaussians, iteration: int, seed: int, scaler: float) -> None:
        """Add iteration's noise to g's means (scaler: the position learning rate times the noise rate)."""
        if g.n == 0:
            return
        lo, hi = seed_words(seed)
        self.rt.launch_items("position_noise", self.kernels()["position_noise"], g.n, PER_GAUSSIAN_WG, self.ctx.frame,
                             np.uint32(g.n), np.uint32(iteration), np.uint32(lo), np.uint32(hi), np.float32(scaler),
                             *g.ordered()[:4])
        self.check(lambda: {"means": g.download_group("means")})
