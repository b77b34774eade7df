"""The forward pipeline for one camera: project -> intersect (compact, depth sort, emit pairs, tile sort,
ranges) -> rasterize. Buffers live in a workspace reused from frame to frame."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import tile_grid
from ..runtime import Runtime
from ..scene.camera import Camera
from .gaussians import DeviceGaussians
from .isect import Intersect, Intersections
from .options import RenderOptions
from .project import Projected, project
from .rasterize import Raster, rasterize
from .tuning import Tuning
from .workspace import Workspace


@dataclass
class RenderResult:
    width: int
    height: int
    tiles_x: int
    tiles_y: int
    proj: Projected
    isect: Intersections
    raster: Raster

    def image(self, rt: Runtime) -> np.ndarray:
        """(H, W, 3) float32 colour, copied to the host."""
        return rt.to_host(self.raster.image, (self.height, self.width, 3))


class Renderer:
    def __init__(self, rt: Runtime, tuning: Tuning | None = None, options: RenderOptions | None = None,
                 poison: bool = False):
        self.rt = rt
        self.tuning = tuning or Tuning.for_device(rt.caps)
        self.options = options or RenderOptions()
        self.defines = self.options.defines()
        self.ws = Workspace(rt, poison)
        self.intersect = Intersect(rt, self.tuning, self.ws, self.options)

    def render(self, gaussians: DeviceGaussians, cam: Camera, sh_degree: int | None = None,
               background=(0.0, 0.0, 0.0)) -> RenderResult:
        tiles_x, tiles_y = tile_grid(cam.width, cam.height)
        degree = gaussians.sh_degree if sh_degree is None else sh_degree
        proj = project(self.rt, self.ws, gaussians, cam, degree, tiles_x, tiles_y, self.defines)
        isect = self.intersect(proj, tiles_x, tiles_y)
        raster = rasterize(self.rt, self.ws, self.tuning, self.defines, proj, isect, cam.width, cam.height,
                           tiles_x, tiles_y, np.asarray(background, np.float32))
        return RenderResult(cam.width, cam.height, tiles_x, tiles_y, proj, isect, raster)
