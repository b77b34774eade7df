"""Float64 NumPy references of the device stages, one module per stage with the same name.

They share no code with the kernels and are written for clarity, not speed; tests compare the device
against them on fresh random inputs.
"""
from .isect import intersect_reference
from .project import project_reference
from .rasterize import rasterize_reference, render_reference

__all__ = ["intersect_reference", "project_reference", "rasterize_reference", "render_reference"]
