"""Gaussian parameters on the device: one flat float32 buffer per group, with spare capacity so that
densification does not reallocate every time. Lane order per Gaussian is the host model's
(dc4gs_cl/model.py): means 3, log_scales 3, quats 4 (w, x, y, z), opacity_logits 1, sh K*3."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..model import GaussianModel
from ..runtime import Runtime

GROWTH = 1.5


def group_widths(sh_coeffs: int) -> dict[str, int]:
    """Floats per Gaussian of each parameter group, in the model's field order."""
    return {"means": 3, "log_scales": 3, "quats": 4, "opacity_logits": 1, "sh": 3 * sh_coeffs}


class DeviceGaussians:
    def __init__(self, rt: Runtime, model: GaussianModel, capacity: int | None = None):
        self.rt = rt
        self.sh_coeffs = model.sh.shape[1]
        self.widths = group_widths(self.sh_coeffs)
        self.n = 0
        self.capacity = 0
        self.buffers: dict[str, cl.Buffer] = {}
        self.upload(model, capacity)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh_coeffs))) - 1

    def upload(self, model: GaussianModel, capacity: int | None = None) -> None:
        """Replace the parameters with the model's (growing the buffers when it does not fit)."""
        if model.sh.shape[1] != self.sh_coeffs:
            raise ValueError("SH degree differs from the device buffers'")
        n = len(model)
        want = max(n, capacity or 0, 1)
        if want > self.capacity:
            self.capacity = max(want, int(self.capacity * GROWTH))
            self.buffers = {k: self.rt.buffer(4 * w * self.capacity) for k, w in self.widths.items()}
        self.n = n
        for name in self.widths:
            self.rt.write(self.buffers[name], getattr(model, name))

    def download(self) -> GaussianModel:
        arrays = {k: self.rt.to_host(self.buffers[k], (self.n, w)) for k, w in self.widths.items()}
        return GaussianModel(means=arrays["means"], log_scales=arrays["log_scales"], quats=arrays["quats"],
                             opacity_logits=arrays["opacity_logits"].reshape(-1),
                             sh=arrays["sh"].reshape(self.n, self.sh_coeffs, 3))
