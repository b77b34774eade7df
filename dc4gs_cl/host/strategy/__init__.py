"""Densification strategies by name."""
from .absgs import AbsGS
from .base import DensifyConfig, DensifyReport, Strategy
from .pixelgs import PixelGS

STRATEGIES = {cls.name: cls for cls in (Strategy, AbsGS, PixelGS)}

__all__ = ["AbsGS", "DensifyConfig", "DensifyReport", "PixelGS", "STRATEGIES", "Strategy"]
