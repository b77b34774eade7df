"""The Gaussians' parameters on the device (runtime.DeviceArrays: one flat float32 buffer per named group, with
spare capacity). The groups and lane order are the host model's (model.PARAM_GROUPS, model.group_widths); Adam's
moments and the gradients use the same layout."""
from __future__ import annotations

import pyopencl as cl

from ..constants import sh_degree_of
from ..model import PARAM_GROUPS, GaussianModel, group_widths
from ..runtime import DeviceArrays, Runtime


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
