"""Per-Gaussian arrays on the device: one flat float32 buffer per named group, with spare capacity so that
densification does not reallocate every time (runtime.grown_size). The parameters' groups and lane order
are the host model's (model.PARAM_GROUPS, model.group_widths); Adam's moments and the gradients use the
same layout."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..constants import sh_degree_of
from ..model import PARAM_GROUPS, GaussianModel, group_widths
from ..runtime import Runtime, grown_size


class DeviceArrays:
    """Named (n, width) float32 arrays on the device sharing one Gaussian count and capacity."""

    def __init__(self, rt: Runtime, widths: dict[str, int], n: int = 0):
        self.rt, self.widths = rt, dict(widths)
        self.n, self.capacity = 0, 0
        self.buffers: dict[str, cl.Buffer] = {}
        self.resize(n)

    def resize(self, n: int) -> None:
        """Set the count; growing past the capacity reallocates (contents are then undefined)."""
        if max(n, 1) > self.capacity:
            self.capacity = grown_size(max(n, 1), self.capacity)
            # Growing keeps no contents, so each old buffer goes before its larger one is made.
            for k, w in self.widths.items():
                self.buffers[k] = None
                self.buffers[k] = self.rt.buffer(4 * w * self.capacity)
        self.n = n

    @property
    def nbytes(self) -> int:
        """Device bytes held (capacity included)."""
        return sum(b.size for b in self.buffers.values())

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

    def zero(self, name: str | None = None) -> None:
        """Zero every group (or only `name`) for the n Gaussians."""
        for k in ([name] if name else self.widths):
            self.rt.fill(self.buffers[k], np.float32(0), 4 * self.widths[k] * self.n)


class DeviceGaussians(DeviceArrays):
    """The Gaussians' parameters on the device."""

    def __init__(self, rt: Runtime, model: GaussianModel):
        self.sh_coeffs = model.sh.shape[1]
        super().__init__(rt, group_widths(self.sh_coeffs), len(model))
        self.upload_model(model)

    @property
    def sh_degree(self) -> int:
        return sh_degree_of(self.sh_coeffs)

    def ordered(self) -> list[cl.Buffer]:
        """The parameter buffers in PARAM_GROUPS order, as the kernels take them."""
        return [self.buffers[name] for name in PARAM_GROUPS]

    def upload_model(self, model: GaussianModel) -> None:
        if model.sh.shape[1] != self.sh_coeffs:
            raise ValueError("SH degree differs from the device buffers'")
        self.upload(model.groups())

    def download_model(self) -> GaussianModel:
        return GaussianModel.from_groups(self.download())
