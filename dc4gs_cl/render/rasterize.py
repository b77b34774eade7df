"""Rasterization stage, forward (kernels/rasterize.cl): colour, final transmittance and the last
blended pair per pixel."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..constants import TILE_SIZE
from .isect import Intersections
from .project import Projected
from .stage import Stage, StageContext


@dataclass
class Raster:
    image: cl.Buffer      # [H*W*3] float32
    final_T: cl.Buffer    # [H*W] float32
    last_pair: cl.Buffer  # [H*W] int32


def raster_defines(ctx: StageContext) -> dict:
    """What the rasterizer's forward and backward kernels share: the switches and the tile work shape."""
    return {**ctx.options.defines(), "PIXELS_PER_ITEM": ctx.tuning.pixels_per_item, "BATCH": ctx.tuning.batch}


def background_value(background) -> np.ndarray:
    """An RGB background as the kernels' float4 argument."""
    bg = np.zeros(4, np.float32)
    bg[:3] = background
    return bg.view(cl.cltypes.float4)[0]


class Rasterize(Stage):
    FILE, KERNELS = "rasterize.cl", ("rasterize",)

    def defines(self) -> dict:
        return raster_defines(self.ctx)

    def __call__(self, proj: Projected, isect: Intersections, width: int, height: int, tiles_x: int, tiles_y: int,
                 background) -> Raster:
        ws = self.ws
        out = Raster(image=ws.get("raster.image", 12 * width * height),
                     final_T=ws.get("raster.final_T", 4 * width * height),
                     last_pair=ws.get("raster.last_pair", 4 * width * height))
        items = TILE_SIZE * TILE_SIZE // self.ctx.tuning.pixels_per_item
        kernel = self.batch_fitted_kernels({}, "rasterize")["rasterize"]
        self.rt.launch("rasterize", kernel, tiles_x * tiles_y * items, items, np.int32(width),
                       np.int32(height), np.int32(tiles_x), background_value(background), isect.ranges,
                       isect.gaussian_of_pair, proj.mean2d, proj.conic_opacity, proj.rgb, proj.alpha_extent,
                       out.image, out.final_T, out.last_pair)
        self.check(lambda: {"image": self.rt.to_host(out.image, (height, width, 3)),
                            "final_T": self.rt.to_host(out.final_T, (height, width))})
        return out
