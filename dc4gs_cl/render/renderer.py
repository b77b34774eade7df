"""The forward pipeline for one camera: project -> intersect (compact, depth sort, emit pairs, tile sort,
ranges) -> rasterize. Scratch buffers live in the stages' shared workspace, reused from frame to frame;
the backward stages of a trainer share the same StageContext (`Renderer.context`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import tile_grid
from ..runtime import Runtime
from ..scene.camera import Camera
from .gaussians import DeviceGaussians
from .isect import Intersect, Intersections
from .options import RenderOptions
from .project import Project, Projected
from .rasterize import Raster, Rasterize
from .stage import StageContext
from .tuning import Tuning


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
                 poison: bool = False, check_finite: bool = False):
        """poison: new scratch buffers start as NaN (tests); check_finite: every stage checks its outputs."""
        self.rt = rt
        self.context = StageContext(rt, tuning, options, poison, check_finite)
        self.project = Project(self.context)
        self.intersect = Intersect(self.context)
        self.rasterize = Rasterize(self.context)

    @property
    def tuning(self) -> Tuning:
        return self.context.tuning

    def render(self, gaussians: DeviceGaussians, cam: Camera, sh_degree: int | None = None,
               background=(0.0, 0.0, 0.0), pair_capacity: int | None = None) -> RenderResult:
        """pair_capacity: room for this many pairs and nothing read back (a frame with more is marked on the device:
        render/isect.py); None: the pair count read back and the buffers sized to fit."""
        tiles_x, tiles_y = tile_grid(cam.width, cam.height)
        degree = gaussians.sh_degree if sh_degree is None else sh_degree
        proj = self.project(gaussians, cam, degree, tiles_x, tiles_y)
        isect = self.intersect(proj, tiles_x, tiles_y, pair_capacity)
        raster = self.rasterize(proj, isect, cam.width, cam.height, tiles_x, tiles_y,
                                np.asarray(background, np.float32))
        return RenderResult(cam.width, cam.height, tiles_x, tiles_y, proj, isect, raster)
