"""Backward stages on the device, one module per kernel file: the rasterizer's backward into per-Gaussian
sums (with the densification statistics a strategy asks for), the projection's backward to the parameters
(Adam's step fused in when training), and DC4GS' split geometry. They share the renderer's StageContext;
backward depends on render, never the reverse, and on nothing of training but the records below both."""
from .project_backward import ProjectBackward
from .rasterize_backward import RasterizeBackward
from .split_geometry import SplitGeometry, geometry_record
from .sums import GRADIENTS, SumsLayout

__all__ = ["GRADIENTS", "ProjectBackward", "RasterizeBackward", "SplitGeometry", "SumsLayout", "geometry_record"]
