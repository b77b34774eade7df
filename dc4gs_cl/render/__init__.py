"""Forward rendering on the device: projection, tile intersection, sorting and rasterization.

Render never imports training code; training builds on it.
"""
from .gaussians import DeviceGaussians
from .options import RenderOptions
from .renderer import Renderer, RenderResult
from .tuning import Tuning

__all__ = ["DeviceGaussians", "RenderOptions", "Renderer", "RenderResult", "Tuning"]
