"""Training on a batch of views per step (--batch B, and the processes of a parallel run, train/parallel.py): each
view's projection backward adds its parameters' gradients to the batch's (kernels/project_backward.cl, ACCUMULATE),
the processes add theirs, and Adam steps once on their mean (kernels/batch_gradients.cl). The learning rates and Adam's
betas follow Grendel's rule for a batch of B views (Zhao et al., "On Scaling Up 3D Gaussian Splatting Training",
2024): rates times sqrt(B), betas to the power B, so that B views in one step move the model about as B steps of one
view would. A batch of one keeps the fused step (project_backward.cl, FUSED_ADAM)."""
from __future__ import annotations

import math

import numpy as np

from ..model import PARAM_GROUPS
from ..records import param_group_defines
from ..render.gaussians import DeviceGaussians
from ..render.stage import PER_GAUSSIAN_WG, Stage, StageContext
from ..runtime import DeviceArrays
from .adam import AdamConfig


def batch_rate_factor(batch: int) -> float:
    """The learning rates' factor for a batch of this many views (Grendel's sqrt scaling)."""
    return math.sqrt(batch)


def batch_adam_config(batch: int, base: AdamConfig = AdamConfig()) -> AdamConfig:
    """Adam's settings for a batch of this many views: its betas to the power batch (Grendel's), eps as it is."""
    return AdamConfig(beta1=base.beta1 ** batch, beta2=base.beta2 ** batch, eps=base.eps)


class BatchGradients(Stage):
    """The parameters' gradients summed over a batch's views (device arrays shaped like the parameters), and Adam's
    step on their mean."""
    FILE, KERNELS = "batch_gradients.cl", ("batch_gradients",)

    def __init__(self, ctx: StageContext, widths: dict[str, int]):
        super().__init__(ctx)
        self.sums = DeviceArrays(ctx.rt, widths, 0)

    def defines(self) -> dict:
        return {**param_group_defines(), "FUSED_ADAM": 1, "ACCUMULATE": 0}

    def start(self, n: int) -> dict:
        """Zeroed sums for a batch over n Gaussians; the buffers each view's backward adds to."""
        self.sums.resize(n)
        self.sums.zero()
        return self.sums.buffers

    def step(self, g: DeviceGaussians, views: int, adam_step: np.void, m: DeviceArrays, v: DeviceArrays,
             regularizers: tuple[float, float] | None = None) -> None:
        """Adam's step on g by the sums' mean over `views` (adam_step, m, v, regularizers: as
        ProjectBackward.step takes them)."""
        if g.n == 0:
            return
        k = self.kernels({"SH_COEFFS": g.sh_coeffs, "REGULARIZED": int(regularizers is not None)})["batch_gradients"]
        reg = [np.float32(r) for r in regularizers] if regularizers is not None else []
        moments = [a.buffers[name] for name in PARAM_GROUPS for a in (m, v)]
        self.rt.launch_items("batch_gradients", k, g.n, PER_GAUSSIAN_WG, self.ctx.frame, np.int32(g.n), *g.ordered(),
                             *[self.sums.buffers[name] for name in PARAM_GROUPS], np.float32(1 / views), *reg,
                             adam_step, *moments)
        self.check(lambda: {**g.download(), **{f"m_{k}": a for k, a in m.download().items()},
                            **{f"v_{k}": a for k, a in v.download().items()}})
