"""The Gaussians being trained: their parameters and Adam's moments on the device, kept aligned, and in and
out of the host as a GaussianSet (densification, checkpoints)."""
from __future__ import annotations

import math

import numpy as np

from ..model import GaussianModel, GaussianSet, group_widths
from ..render.gaussians import DeviceGaussians
from ..runtime import Runtime
from .adam import Adam, AdamConfig


class TrainableGaussians:
    def __init__(self, rt: Runtime, model: GaussianModel, adam: AdamConfig = AdamConfig()):
        self.params = DeviceGaussians(rt, model)
        self.widths = group_widths(self.params.sh_coeffs)
        self.adam = Adam(rt, self.widths, self.params.n, adam)

    @property
    def n(self) -> int:
        return self.params.n

    def download(self) -> GaussianSet:
        return GaussianSet(self.params.download(), self.adam.m.download(), self.adam.v.download())

    def upload(self, gs: GaussianSet) -> None:
        if set(gs.params) != set(self.widths) or any(a.shape != (gs.n, self.widths[k]) for k, a in gs.params.items()):
            raise ValueError("the Gaussians' arrays do not match the model's layout")
        self.params.upload(gs.params)
        self.adam.m.upload(gs.m)
        self.adam.v.upload(gs.v)

    def limit_opacity(self, ceiling: float) -> None:
        """Opacities above the ceiling drop to it (the 3DGS reset to 0.01, AbsGS' clamp to 0.8) and the opacities'
        Adam moments restart."""
        name = "opacity_logits"
        self.params.upload_group(name, np.minimum(self.params.download_group(name), math.log(ceiling / (1 - ceiling))))
        self.adam.m.zero(name)
        self.adam.v.zero(name)
