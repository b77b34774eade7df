"""Per-Gaussian arrays on the device: one flat float32 buffer per named group, with spare capacity so that
densification does not reallocate every time. The parameters' lane order per Gaussian is the host
model's (dc4gs_cl/model.py): means 3, log_scales 3, quats 4 (w, x, y, z), opacity_logits 1, sh K*3;
gradients and optimiser moments use the same layout."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..constants import sh_degree_of
from ..model import GaussianModel
from ..runtime import BUFFER_GROWTH, Runtime

PARAM_GROUPS = ("means", "log_scales", "quats", "opacity_logits", "sh")


def group_widths(sh_coeffs: int) -> dict[str, int]:
    """Floats per Gaussian of each parameter group, in the model's field order."""
    return {"means": 3, "log_scales": 3, "quats": 4, "opacity_logits": 1, "sh": 3 * sh_coeffs}


class DeviceArrays:
    """Named (n, width) float32 arrays on the device sharing one Gaussian count and capacity."""

    def __init__(self, rt: Runtime, widths: dict[str, int], n: int = 0, capacity: int = 0):
        self.rt, self.widths = rt, dict(widths)
        self.n, self.capacity = 0, 0
        self.buffers: dict[str, cl.Buffer] = {}
        self.resize(n, capacity)

    def resize(self, n: int, capacity: int = 0) -> None:
        """Set the count; growing past the capacity reallocates (contents are then undefined)."""
        want = max(n, capacity, 1)
        if want > self.capacity:
            self.capacity = max(want, int(self.capacity * BUFFER_GROWTH))
            self.buffers = {k: self.rt.buffer(4 * w * self.capacity) for k, w in self.widths.items()}
        self.n = n

    def upload(self, arrays: dict[str, np.ndarray]) -> None:
        """Replace the contents (and the count) with host arrays of shape (n, ...)."""
        n = len(next(iter(arrays.values())))
        self.resize(n)
        for name in self.widths:
            self.rt.write(self.buffers[name], np.ascontiguousarray(arrays[name], dtype=np.float32))

    def download(self) -> dict[str, np.ndarray]:
        return {k: self.download_group(k) for k in self.widths}

    def download_group(self, name: str) -> np.ndarray:
        return self.rt.to_host(self.buffers[name], (self.n, self.widths[name]))

    def upload_group(self, name: str, array: np.ndarray) -> None:
        self.rt.write(self.buffers[name], np.ascontiguousarray(array, dtype=np.float32).reshape(self.n, self.widths[name]))

    def zero(self) -> None:
        for k, w in self.widths.items():
            self.rt.fill(self.buffers[k], np.float32(0), 4 * w * self.n)


class DeviceGaussians(DeviceArrays):
    """The Gaussians' parameters on the device."""

    def __init__(self, rt: Runtime, model: GaussianModel, capacity: int = 0):
        self.sh_coeffs = model.sh.shape[1]
        super().__init__(rt, group_widths(self.sh_coeffs), len(model), capacity)
        self.upload_model(model)

    @property
    def sh_degree(self) -> int:
        return sh_degree_of(self.sh_coeffs)

    def upload_model(self, model: GaussianModel) -> None:
        if model.sh.shape[1] != self.sh_coeffs:
            raise ValueError("SH degree differs from the device buffers'")
        self.upload({k: getattr(model, k).reshape(len(model), self.widths[k]) for k in PARAM_GROUPS})

    def download_model(self) -> GaussianModel:
        a = self.download()
        return GaussianModel(means=a["means"], log_scales=a["log_scales"], quats=a["quats"],
                             opacity_logits=a["opacity_logits"].reshape(-1), sh=a["sh"].reshape(self.n, self.sh_coeffs, 3))
