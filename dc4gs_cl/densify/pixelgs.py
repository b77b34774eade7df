"""Pixel-GS: the per-view gradient norm weighted by the pixels the Gaussian covers (and scaled down
near the camera), averaged over those pixels rather than over views, for both clone and split."""
from __future__ import annotations

from ..statistics import GRAD_PER_PIXEL
from .strategy import Strategy


class PixelGS(Strategy):
    name = "pixelgs"
    clone_criterion = GRAD_PER_PIXEL
    base_split_criterion = GRAD_PER_PIXEL
