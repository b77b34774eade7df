"""Backward stages on the device, one module per kernel file: the rasterizer's backward into per-Gaussian
sums (with the densification statistics a strategy asks for, folded into its window: a WindowFold, plain data),
the projection's backward to the parameters (Adam's step fused in when training), and DC4GS' split geometry.
They share the renderer's StageContext; backward depends on render and statistics, never on training: it takes
what to gather (statistics.SumsLayout) and where to fold (WindowFold) as data, Adam's step as a records.ADAM_STEP
value and the moments as device arrays."""
from .densify_stats import DensifyStats, WindowFold
from .project_backward import ProjectBackward
from .rasterize_backward import RasterizeBackward
from .split_geometry import SplitGeometry

__all__ = ["DensifyStats", "ProjectBackward", "RasterizeBackward", "SplitGeometry", "WindowFold"]
