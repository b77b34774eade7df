"""Adaptive density control: strategies (3DGS, AbsGS, Pixel-GS, each with or without DC4GS) that own their
statistics on the device and decide clone, split, prune and opacity limits; the operations on the
Gaussians (ops); the statistics' one description (statistics)."""
from .absgs import AbsGS
from .dc4gs import DC4GSConfig
from .ops import GaussianSet
from .pixelgs import PixelGS
from .strategy import Actions, DensifyConfig, DensifyReport, Gathering, Strategy

STRATEGIES = {cls.name: cls for cls in (Strategy, AbsGS, PixelGS)}

__all__ = ["AbsGS", "Actions", "DC4GSConfig", "DensifyConfig", "DensifyReport", "GaussianSet", "Gathering",
           "PixelGS", "STRATEGIES", "Strategy"]
