"""Split geometry stage (kernels/split_geometry.cl): where each Gaussian's DC4GS split candidates fall in
this view, for the rasterizer backward's split sums (the DC-guided split, DCS)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..layout import Record
from ..records import camera_value
from ..render.gaussians import DeviceGaussians
from ..render.renderer import RenderResult
from ..render.stage import PER_GAUSSIAN_WG, Stage
from ..scene.camera import Camera


def geometry_record(candidates: int) -> Record:
    """Per Gaussian, px: the first candidate's pixel (origin), the unit direction of the projected axis
    (dir; (0, 0): no split line in this view) and t_1 .. t_{N-1}, the other candidates' positions along it
    (t_0 = 0)."""
    return Record("GEO", [("origin", 2), ("dir", 2), ("t", candidates - 1)])


# The densification window's column (host/densify/statistics.py) whose non-zero value withholds a Gaussian's
# split line: DCS' tracking stops gathering split costs for Gaussians that cannot reach the split threshold.
SKIP_SPLIT = "skip_split"
NO_WINDOW = Record("WIN", [(SKIP_SPLIT, 1)])   # no window: every Gaussian tracked (its skip flag 0)


class SplitGeometry(Stage):
    FILE, KERNELS = "split_geometry.cl", ("split_geometry",)

    def __call__(self, g: DeviceGaussians, cam: Camera, res: RenderResult, candidates: int, min_scale: float = 0.0,
                 window: tuple[cl.Buffer, Record] | None = None) -> cl.Buffer:
        """Per visible Gaussian whose largest scale exceeds min_scale (only those can be split) and that the
        window still tracks (window: the densification window's buffer and record, host/densify; None:
        every one), where its split candidates fall in this view: geometry_record(candidates) rows."""
        n, record = g.n, geometry_record(candidates)
        geometry = self.ws.get("backward.split_geometry", 4 * record.width * max(n, 1))
        if window is None:
            no_window = self.ws.get("backward.no_window", 4 * max(n, 1))
            self.rt.fill(no_window, np.float32(0), 4 * n)
            window = (no_window, NO_WINDOW)
        buffer, window_record = window
        if n:
            variant = {"SPLIT_CANDIDATES": candidates, **record.defines(), **window_record.defines()}
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
