"""Float64 NumPy references of the device stages: projection (and its backward), tile intersection,
rasterizer (forward and backward), loss and the DC4GS sums, each module named after its kernel file.
Sort, scan and Adam need none: their tests compare with NumPy's sort, cumsum and Adam's few lines.

They share no code with the kernels and are written for clarity, not speed; tests compare the device
against them on fresh random inputs.
"""
from .isect import intersect_reference
from .project import project_reference
from .rasterize import rasterize_reference, render_reference

__all__ = ["intersect_reference", "project_reference", "rasterize_reference", "render_reference"]
