"""Backward stages: rasterizer backward (kernels/rasterize_backward.cl) into per-Gaussian sums, and the
projection backward (kernels/project_backward.cl) from those sums to the parameters' gradients, or, in
training, straight to Adam's step on the parameters (the gradients never stored)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pyopencl as cl

from ..constants import TILE_SIZE
from ..runtime import Runtime
from ..scene.camera import Camera
from .gaussians import PARAM_GROUPS, DeviceGaussians
from .project import PER_GAUSSIAN_WG, camera_struct
from .rasterize import rasterize_defines
from .renderer import RenderResult
from .tuning import Tuning
from .workspace import Workspace

if TYPE_CHECKING:   # annotation only: rendering never imports training code
    from ..host.adam import AdamStep


@dataclass(frozen=True)
class SumsLayout:
    """Per-Gaussian floats the rasterizer backward accumulates over one view, in this order:
    mean2d (2, px), conic (3), opacity (1), rgb (3); with stats: abs (2, sum |g_x|, |g_y| in NDC
    units), pixels (1); with dc_stats: dc (3, sum of g/|g| and the count); with split_candidates N:
    split (5 N: for each candidate k, the left side's sum of u_x, u_y, the count, sum |g_x|, |g_y|; the
    right side is the total, from dc and abs, minus the left)."""
    stats: bool = False
    dc_stats: bool = False
    split_candidates: int = 0

    def __post_init__(self):
        if self.dc_stats and not self.stats:
            raise ValueError("directional-consistency statistics need the base statistics")
        if self.split_candidates and not self.dc_stats:
            raise ValueError("split costs need the directional-consistency statistics")
        if self.split_candidates and self.split_candidates % 2 == 0:
            raise ValueError("the number of split candidates must be odd")

    @property
    def fields(self) -> dict[str, tuple[int, int]]:
        """name -> (offset, width)."""
        widths = [("mean2d", 2), ("conic", 3), ("opacity", 1), ("rgb", 3)]
        if self.stats:
            widths += [("abs", 2), ("pixels", 1)]
        if self.dc_stats:
            widths += [("dc", 3)]
        if self.split_candidates:
            widths += [("split", 5 * self.split_candidates)]
        out, at = {}, 0
        for name, w in widths:
            out[name] = (at, w)
            at += w
        return out

    @property
    def width(self) -> int:
        return sum(w for _, w in self.fields.values())

    def defines(self) -> dict[str, int]:
        d = {"SUMS_PER_GAUSSIAN": self.width, "STATS": int(self.stats), "DC_STATS": int(self.dc_stats),
             "SPLIT_CANDIDATES": self.split_candidates}
        d.update({f"SUM_{name.upper()}": at for name, (at, _) in self.fields.items()})
        return d

    def split(self, sums: np.ndarray) -> dict[str, np.ndarray]:
        """(N, width) host array -> named views."""
        return {name: sums[:, at:at + w].squeeze(1) if w == 1 else sums[:, at:at + w]
                for name, (at, w) in self.fields.items()}


def split_geometry_width(candidates: int) -> int:
    """Floats per Gaussian in the split geometry (kernels/split_geometry.cl: c0, dir, t_1..t_{N-1}, px)."""
    return candidates + 3


def split_geometry(rt: Runtime, ws: Workspace, g: DeviceGaussians, cam: Camera, res: RenderResult,
                   candidates: int, min_scale: float = 0.0,
                   window: tuple[cl.Buffer, dict] | None = None) -> cl.Buffer:
    """Per visible Gaussian whose largest scale exceeds min_scale (only those can be split) and that the
    window still tracks (window: the window statistics' buffer and its layout's defines, host/stats.py;
    None: every one), where its split candidates fall in this view (kernels/split_geometry.cl)."""
    n = g.n
    geometry = ws.get("backward.split_geometry", 4 * split_geometry_width(candidates) * max(n, 1))
    if window is None:
        no_window = ws.get("backward.no_window", 4 * max(n, 1))
        rt.fill(no_window, np.float32(0), 4 * n)
        window = (no_window, {"WINDOW_WIDTH": 1, "WIN_SKIP_SPLIT": 0})
    window, window_defines = window
    if n:
        k = rt.kernel("split_geometry.cl", "split_geometry", {"SPLIT_CANDIDATES": candidates, **window_defines})
        b = g.buffers
        rt.launch_items("split_geometry", k, n, PER_GAUSSIAN_WG, np.int32(n), camera_struct(cam),
                  np.float32(min_scale), b["means"], b["log_scales"], b["quats"], res.proj.radius, window, geometry)
    return geometry


def rasterize_backward(rt: Runtime, ws: Workspace, tuning: Tuning, defines: dict, layout: SumsLayout,
                       res: RenderResult, dL_dimage: cl.Buffer, background,
                       geometry: cl.Buffer | None = None) -> cl.Buffer:
    """Per-Gaussian sums (N x layout.width floats) of this view's gradients and statistics; split costs need
    the view's split geometry."""
    if layout.split_candidates and geometry is None:
        raise ValueError("split costs need the split geometry of the view")
    n, p = res.proj.n, res.isect.n_pairs
    sums = ws.get("backward.sums", 4 * layout.width * max(n, 1))
    options = {**rasterize_defines(tuning, defines), **layout.defines(), "PAIR_SUMS": int(tuning.pair_sums)}
    if tuning.pair_sums:
        target = ws.get("backward.pair_sums", 4 * layout.width * max(p, 1))
    else:
        target = sums
        rt.fill(sums, np.float32(0), 4 * layout.width * n)
    k = rt.kernel("rasterize_backward.cl", "rasterize_backward", options)
    items = TILE_SIZE * TILE_SIZE // tuning.pixels_per_item
    bg = np.zeros(4, np.float32)
    bg[:3] = background
    rt.launch("rasterize_backward", k, res.tiles_x * res.tiles_y * items, items, np.int32(res.width),
              np.int32(res.height), np.int32(res.tiles_x), bg.view(cl.cltypes.float4)[0], res.isect.ranges,
              res.isect.gaussian_of_pair, res.proj.mean2d, res.proj.conic_opacity, res.proj.rgb,
              res.proj.alpha_extent, res.raster.final_T, res.raster.last_pair, dL_dimage,
              geometry if geometry is not None else sums, target)
    if tuning.pair_sums and n:
        reduce = rt.kernel("rasterize_backward.cl", "sum_pairs", options)
        rt.launch_items("rasterize_backward", reduce, n, PER_GAUSSIAN_WG, np.uint32(n),
                  res.proj.tiles_touched, res.isect.pair_first, res.isect.pair_of_emission, target,
                  geometry if geometry is not None else sums, sums)
    return sums


def project_backward(rt: Runtime, g: DeviceGaussians, cam: Camera, sh_degree: int, res: RenderResult,
                     sums: cl.Buffer, layout: SumsLayout, grads: dict[str, cl.Buffer] | None = None,
                     adam_step: AdamStep | None = None) -> None:
    """From this view's per-Gaussian sums, either the parameters' gradients into grads (buffers shaped like the
    parameters, see gaussians.group_widths; zero for Gaussians not visible in the view) or, given adam_step
    (host.adam.Adam.fused_step), Adam's step on the parameters in place, the gradients never stored."""
    if (grads is None) == (adam_step is None):
        raise ValueError("project_backward writes gradients or takes an Adam step: give exactly one")
    n = g.n
    if n == 0:
        return
    fused = adam_step is not None
    k = rt.kernel("project_backward.cl", "project_backward",
                  {"SH_COEFFS": g.sh_coeffs, "FUSED_ADAM": int(fused), **layout.defines()})
    b = g.buffers
    if fused:
        outputs = [adam_step.struct] + [m[name] for name in PARAM_GROUPS
                                        for m in (adam_step.m.buffers, adam_step.v.buffers)]
    else:
        outputs = [grads[name] for name in PARAM_GROUPS]
    rt.launch_items("project_backward", k, n, PER_GAUSSIAN_WG, np.int32(n), camera_struct(cam),
              np.int32(min(sh_degree, g.sh_degree)), *(b[name] for name in PARAM_GROUPS), res.proj.radius, sums, *outputs)
