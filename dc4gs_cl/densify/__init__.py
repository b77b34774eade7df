"""Adaptive density control: strategies (3DGS, AbsGS, Pixel-GS, each with or without DC4GS; MCMC) that own their
statistics on the device (the window, window.py; what it holds is described once in statistics.py) and decide
clone, split, prune and opacity limits; the operations on the Gaussians (ops); DC4GS' criterion and split
placement (dc4gs)."""
from ..config import DC4GSConfig, DensifyConfig   # the settings, device-free there; here for the strategies' users
from .absgs import AbsGS
from .mcmc import MCMC
from .pixelgs import PixelGS
from .strategy import Actions, DensifyReport, Gathering, Strategy

STRATEGIES = {cls.name: cls for cls in (Strategy, AbsGS, PixelGS, MCMC)}   # keyed by config.STRATEGY_NAMES

__all__ = ["AbsGS", "Actions", "DC4GSConfig", "DensifyConfig", "DensifyReport", "Gathering", "MCMC",
           "PixelGS", "STRATEGIES", "Strategy"]
