"""Our Adam (PyTorch's update rule, eps 1e-15 as in 3DGS) and the learning-rate schedules.

The host owns the logic: step counts per group, learning rates, which groups step. The device applies the
element-wise update inside the projection's backward (kernels/adam.h, fused into project_backward.cl), so
the parameters' gradients are never stored and the parameters never leave the device on the hot path.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..render.gaussians import PARAM_GROUPS, DeviceArrays   # PARAM_GROUPS: in the order of ADAM_MEANS .. ADAM_SH
from ..runtime import Runtime

# Keep in step with AdamStep in kernels/adam.h: one rate per parameter group, then the SH bands above the DC band.
ADAM_STEP_DTYPE = np.dtype([("lr", np.float32, len(PARAM_GROUPS) + 1), ("c1", np.float32, len(PARAM_GROUPS)),
                            ("c2", np.float32, len(PARAM_GROUPS)), ("beta1", np.float32), ("beta2", np.float32),
                            ("eps", np.float32), ("stepping", np.uint32)])


@dataclass(frozen=True)
class AdamConfig:
    beta1: float = 0.9
    beta2: float = 0.999
    eps: float = 1e-15


@dataclass
class AdamStep:
    """What the fused kernel needs for one step: the AdamStep struct and the moments' buffers."""
    struct: np.void
    m: DeviceArrays
    v: DeviceArrays


def exponential_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear from lr_init at step 0 to lr_final at max_steps (the 3DGS position schedule)."""
    t = float(np.clip(step / max(max_steps, 1), 0.0, 1.0))
    return float(np.exp(np.log(lr_init) * (1 - t) + np.log(lr_final) * t))


class Adam:
    """Moments m and v on the device (same groups and layout as the parameters), step count per group."""

    def __init__(self, rt: Runtime, widths: dict[str, int], n: int, config: AdamConfig = AdamConfig()):
        if set(widths) != set(PARAM_GROUPS):
            raise ValueError(f"Adam steps the groups {PARAM_GROUPS}, not {tuple(widths)}")
        self.config = config
        self.m = DeviceArrays(rt, widths, n)
        self.v = DeviceArrays(rt, widths, n)
        self.m.zero()
        self.v.zero()
        self.steps = {k: 0 for k in widths}

    def fused_step(self, lrs: dict[str, float | tuple[float, float]]) -> AdamStep:
        """Counts one step of every group named in lrs and returns what project_backward needs to take it.
        The SH group's rate is a pair (DC band, higher bands)."""
        cfg = self.config
        s = np.zeros(1, ADAM_STEP_DTYPE)[0]
        s["beta1"], s["beta2"], s["eps"] = cfg.beta1, cfg.beta2, cfg.eps
        stepping = 0
        for g, name in enumerate(PARAM_GROUPS):
            if name not in lrs:
                continue
            self.steps[name] += 1
            t = self.steps[name]
            stepping |= 1 << g
            s["c1"][g], s["c2"][g] = 1 - cfg.beta1 ** t, 1 - cfg.beta2 ** t
            lr = lrs[name]
            if name == "sh":
                s["lr"][g], s["lr"][len(PARAM_GROUPS)] = lr
            else:
                s["lr"][g] = lr
        s["stepping"] = stepping
        return AdamStep(s, self.m, self.v)
