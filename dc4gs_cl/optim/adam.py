"""Our Adam (PyTorch's update rule, eps 1e-15 as in 3DGS) and the learning-rate schedules.

The host owns the logic: step counts per group, learning rates, which groups step. The device applies the
element-wise update inside the projection's backward (kernels/adam.h, fused into project_backward.cl), so
the parameters' gradients are never stored and the parameters never leave the device on the hot path.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import PARAM_GROUPS
from ..records import ADAM_STEP, SH_REST_RATE
from ..runtime import DeviceArrays, Runtime


@dataclass(frozen=True)
class AdamConfig:
    beta1: float = 0.9
    beta2: float = 0.999
    eps: float = 1e-15


def exponential_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear from lr_init at step 0 to lr_final at max_steps (the 3DGS position schedule)."""
    t = float(np.clip(step / max(max_steps, 1), 0.0, 1.0))
    return float(np.exp(np.log(lr_init) * (1 - t) + np.log(lr_final) * t))


def delayed_lr(step: int, delay_steps: int, delay_mult: float) -> float:
    """The factor the Inria code's lr_delay_steps and lr_delay_mult put on a rate: delay_mult at step 0, rising
    along a quarter sine to 1 at delay_steps (1 throughout where delay_steps is 0)."""
    if delay_steps <= 0:
        return 1.0
    return float(delay_mult + (1 - delay_mult) * np.sin(0.5 * np.pi * np.clip(step / delay_steps, 0.0, 1.0)))


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

    def step_value(self, lrs: dict[str, float | tuple[float, float]]) -> np.void:
        """Counts one step of every group named in lrs and returns the records.ADAM_STEP value that
        project_backward's fused step takes. The SH group's rate is a pair (DC band, higher bands)."""
        cfg = self.config
        lr = np.zeros(ADAM_STEP.widths()["lr"])
        c1, c2 = np.zeros(len(PARAM_GROUPS)), np.zeros(len(PARAM_GROUPS))
        stepping = 0
        for g, name in enumerate(PARAM_GROUPS):
            if name not in lrs:
                continue
            self.steps[name] += 1
            t = self.steps[name]
            stepping |= 1 << g
            c1[g], c2[g] = 1 - cfg.beta1 ** t, 1 - cfg.beta2 ** t
            if name == "sh":
                lr[g], lr[SH_REST_RATE] = lrs[name]
            else:
                lr[g] = lrs[name]
        return ADAM_STEP.pack(lr=lr, c1=c1, c2=c2, beta1=cfg.beta1, beta2=cfg.beta2, eps=cfg.eps, stepping=stepping)


def one_group_step(lr: float, t: int, config: AdamConfig = AdamConfig()) -> np.void:
    """The records.ADAM_STEP value of a parameter set with an Adam of its own (train --exposure's corrections,
    backward/exposure.py): its t-th step (t >= 1) at rate lr, in slot 0; t = 0: no step."""
    lr_, c1, c2 = np.zeros(ADAM_STEP.widths()["lr"]), np.zeros(len(PARAM_GROUPS)), np.zeros(len(PARAM_GROUPS))
    if t:
        lr_[0], c1[0], c2[0] = lr, 1 - config.beta1 ** t, 1 - config.beta2 ** t
    return ADAM_STEP.pack(lr=lr_, c1=c1, c2=c2, beta1=config.beta1, beta2=config.beta2, eps=config.eps,
                          stepping=int(t > 0))
