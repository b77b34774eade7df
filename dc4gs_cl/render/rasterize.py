"""Rasterization stage, forward (kernels/rasterize.cl): colour, final transmittance and the last
blended pair per pixel."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..constants import TILE_SIZE
from ..runtime import Runtime
from .isect import Intersections
from .project import Projected
from .tuning import Tuning
from .workspace import Workspace


@dataclass
class Raster:
    image: cl.Buffer      # [H*W*3] float32
    final_T: cl.Buffer    # [H*W] float32
    last_pair: cl.Buffer  # [H*W] int32


def rasterize_defines(tuning: Tuning, defines: dict) -> dict:
    return {**defines, "PIXELS_PER_ITEM": tuning.pixels_per_item, "BATCH": tuning.batch}


def rasterize(rt: Runtime, ws: Workspace, tuning: Tuning, defines: dict, proj: Projected, isect: Intersections,
              width: int, height: int, tiles_x: int, tiles_y: int, background) -> Raster:
    out = Raster(image=ws.get("raster.image", 12 * width * height), final_T=ws.get("raster.final_T", 4 * width * height),
                 last_pair=ws.get("raster.last_pair", 4 * width * height))
    k = rt.kernel("rasterize.cl", "rasterize", rasterize_defines(tuning, defines))
    items = TILE_SIZE * TILE_SIZE // tuning.pixels_per_item
    bg = np.zeros(4, np.float32)
    bg[:3] = background
    rt.launch("rasterize", k, tiles_x * tiles_y * items, items, np.int32(width), np.int32(height), np.int32(tiles_x),
              bg.view(cl.cltypes.float4)[0], isect.ranges, isect.gaussian_of_pair, proj.mean2d,
              proj.conic_opacity, proj.rgb, proj.alpha_extent, out.image, out.final_T, out.last_pair)
    return out
