"""Rasterizer backward stage (kernels/rasterize_backward.cl): per-Gaussian sums of this view's gradients
and of the densification statistics the layout asks for (backward/sums.py)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..constants import TILE_SIZE
from ..render.rasterize import background_value, raster_defines
from ..render.renderer import RenderResult
from ..render.stage import PER_GAUSSIAN_WG, Stage, visible_rows
from .sums import SumsLayout


class RasterizeBackward(Stage):
    FILE, KERNELS = "rasterize_backward.cl", ("rasterize_backward", "sum_pairs")

    def fitted_kernels(self, variant: dict) -> dict[str, cl.Kernel]:
        """A variant's kernels whose local arrays (a batch of Gaussians, their split geometry and, in the
        cooperative shapes, their sums: 62 KB with DC4GS' split sums at the GPU shape's 256) fit the device."""
        return self.batch_fitted_kernels(variant, "rasterize_backward")

    def defines(self) -> dict:
        # pair_sums: one slot per (tile, Gaussian) pair, summed per Gaussian in a fixed order (deterministic);
        # otherwise float atomics into the per-Gaussian sums (--low-memory).
        return {**raster_defines(self.ctx), "PAIR_SUMS": int(self.ctx.tuning.pair_sums)}

    def __call__(self, res: RenderResult, dL_dimage: cl.Buffer, background, layout: SumsLayout,
                 geometry: cl.Buffer | None = None, keep: cl.Buffer | None = None) -> cl.Buffer:
        """Per-Gaussian sums (N x layout.width floats); split sums need the view's split geometry. keep: the
        view's mask (H x W uint8, 0 = masked out), whose masked pixels add nothing."""
        if layout.split_candidates and geometry is None:
            raise ValueError("split costs need the split geometry of the view")
        rt, pair_sums = self.rt, self.ctx.tuning.pair_sums
        n, p = res.proj.n, res.isect.n_pairs
        sums = self.ws.get("backward.sums", 4 * layout.width * max(n, 1))
        if pair_sums:
            target = self.ws.get("backward.pair_sums", 4 * layout.width * max(p, 1))
        else:
            target = sums
            rt.fill(sums, np.float32(0), 4 * layout.width * n)
        k = self.fitted_kernels({**layout.defines(), "PIXEL_MASK": int(keep is not None)})
        items = TILE_SIZE * TILE_SIZE // self.ctx.tuning.pixels_per_item
        rt.launch("rasterize_backward", k["rasterize_backward"], res.tiles_x * res.tiles_y * items, items,
                  np.int32(res.width), np.int32(res.height), np.int32(res.tiles_x), background_value(background),
                  res.isect.ranges, res.isect.gaussian_of_pair, res.proj.mean2d, res.proj.conic_opacity,
                  res.proj.rgb, res.proj.alpha_extent, res.raster.final_T, res.raster.last_pair, dL_dimage,
                  geometry if geometry is not None else sums, *([keep] if keep is not None else []), target)
        if pair_sums and n:
            rt.launch_items("rasterize_backward", k["sum_pairs"], n, PER_GAUSSIAN_WG, np.uint32(n),
                            res.proj.tiles_touched, res.isect.pair_first, res.isect.pair_of_emission, target,
                            geometry if geometry is not None else sums, sums)
        self.check(lambda: {"sums": visible_rows(rt, sums, rt.to_host(res.proj.radius, n, np.int32), layout.width)})
        return sums
