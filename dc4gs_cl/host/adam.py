"""Our Adam (PyTorch's update rule, eps 1e-15 as in 3DGS) and the learning-rate schedules.

The host owns the logic: step counts per group, learning rates, which groups step; the device applies
the element-wise update (kernels/adam.cl), so parameters never leave the device on the hot path.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..render.gaussians import DeviceArrays
from ..runtime import Runtime

ADAM_WG = 256


@dataclass(frozen=True)
class AdamConfig:
    beta1: float = 0.9
    beta2: float = 0.999
    eps: float = 1e-15


def exponential_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear from lr_init at step 0 to lr_final at max_steps (the 3DGS position schedule)."""
    t = float(np.clip(step / max(max_steps, 1), 0.0, 1.0))
    return float(np.exp(np.log(lr_init) * (1 - t) + np.log(lr_final) * t))


class Adam:
    """Moments m and v on the device (same groups and layout as the parameters), step count per group."""

    def __init__(self, rt: Runtime, widths: dict[str, int], n: int, config: AdamConfig = AdamConfig()):
        self.rt, self.config = rt, config
        self.m = DeviceArrays(rt, widths, n)
        self.v = DeviceArrays(rt, widths, n)
        self.m.zero()
        self.v.zero()
        self.steps = {k: 0 for k in widths}
        self.kernel = rt.kernel("adam.cl", "adam_step")

    def step(self, params: DeviceArrays, grads: DeviceArrays, lrs: dict[str, float | tuple[float, float]],
             split_lanes: int = 3) -> None:
        """One step of every group named in lrs. A pair of rates (low, high) steps the first split_lanes
        floats of each Gaussian's row with low and the rest with high (SH: DC band vs the others)."""
        cfg = self.config
        for name, lr in lrs.items():
            self.steps[name] += 1
            t = self.steps[name]
            width, rows = params.widths[name], params.n
            low, high = lr if isinstance(lr, tuple) else (lr, lr)
            if rows == 0:
                continue
            per_group = max(1, ADAM_WG // width)
            self.rt.launch("adam", self.kernel, (width, -(-rows // per_group) * per_group), (width, per_group),
                           np.uint32(rows), np.uint32(split_lanes if isinstance(lr, tuple) else width),
                           np.float32(low), np.float32(high), np.float32(cfg.beta1), np.float32(cfg.beta2),
                           np.float32(cfg.eps), np.float32(1 - cfg.beta1 ** t), np.float32(1 - cfg.beta2 ** t),
                           params.buffers[name], grads.buffers[name], self.m.buffers[name], self.v.buffers[name])
