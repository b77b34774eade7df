"""Forward rendering on the device: projection, tile intersection, sorting and rasterization, one stage
host per kernel file (stage.py).

Render imports nothing of the backward or of training; both build on it.
"""
from .gaussians import DeviceGaussians
from .options import RenderOptions
from .renderer import Renderer, RenderResult
from .stage import StageContext
from .tuning import Tuning

__all__ = ["DeviceGaussians", "RenderOptions", "Renderer", "RenderResult", "StageContext", "Tuning"]
