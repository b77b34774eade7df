"""Pixel-GS: the per-view gradient norm weighted by the pixels the Gaussian covers (and scaled down
near the camera), averaged over those pixels rather than over views, for both clone and split."""
from __future__ import annotations

import numpy as np

from .base import Strategy, mean_per_view


class PixelGS(Strategy):
    name = "pixelgs"

    split_columns = ("pix_grad", "pix")
    dcc_base_columns = ("dcc_pix", "pix")

    def clone_values(self, stats: dict[str, np.ndarray]) -> np.ndarray:
        return mean_per_view(stats["pix_grad"], stats["pix"])
