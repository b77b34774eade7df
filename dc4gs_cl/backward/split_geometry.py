"""Split geometry stage (kernels/split_geometry.cl): where each Gaussian's DC4GS split candidates fall in
this view, for the rasterizer backward's split sums (the DC-guided split, DCS)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..layout import Record
from ..records import camera_value, distortion_define
from ..render.gaussians import DeviceGaussians
from ..render.renderer import RenderResult
from ..render.stage import PER_GAUSSIAN_WG, Stage
from ..scene.camera import Camera
from ..statistics import NO_WINDOW, geometry_record
from .densify_stats import WindowFold

# Workspace buffers (render/workspace.py)
SPLIT_GEOMETRY = "backward.split_geometry"   # [N*GEO_WIDTH] the view's split geometry (returned)
NO_WINDOW_ROWS = "backward.no_window"        # [N] zeros: the skip flags when no window is given


class SplitGeometry(Stage):
    FILE, KERNELS = "split_geometry.cl", ("split_geometry",)

    def __call__(self, g: DeviceGaussians, cam: Camera, res: RenderResult, candidates: int, min_scale: float = 0.0,
                 window: WindowFold | None = None) -> cl.Buffer:
        """Per visible Gaussian whose largest scale exceeds min_scale (only those can be split) and that the
        window still tracks (its skip_split column; None: every one), where its split candidates fall in this
        view: geometry_record(candidates) rows."""
        n, record = g.n, geometry_record(candidates)
        geometry = self.ws.get(SPLIT_GEOMETRY, 4 * record.width * max(n, 1))
        if window is None:
            buffer, window_record = self.ws.get(NO_WINDOW_ROWS, 4 * max(n, 1)), NO_WINDOW
            self.rt.fill(buffer, np.float32(0), 4 * n)
        else:
            buffer, window_record = window.rows, window.record
        if n:
            variant = {"SPLIT_CANDIDATES": candidates, **record.defines(), **window_record.defines(),
                       **distortion_define(cam)}
            b = g.buffers
            self.rt.launch_items("split_geometry", self.kernels(variant)["split_geometry"], n, PER_GAUSSIAN_WG,
                                 np.int32(n), camera_value(cam), np.float32(min_scale), b["means"], b["log_scales"],
                                 b["quats"], res.proj.radius, buffer, geometry)
            self.check(lambda: self.lines(geometry, n, record))
        return geometry

    def lines(self, geometry: cl.Buffer, n: int, record: Record) -> dict[str, np.ndarray]:
        """The rows that hold a split line (the only ones the kernel fills in full)."""
        rows = self.rt.to_host(geometry, (n, record.width))
        return {"geometry": rows[(rows[:, record.offsets["dir"]] != 0) | (rows[:, record.offsets["dir"] + 1] != 0)]}
