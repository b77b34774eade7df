"""Densification statistics on the device: each view's per-Gaussian sums folded into accumulators that
live until the next densification step (kernels/densify_stats.cl). The host reads them only there."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..render.backward import SumsLayout
from ..render.project import PER_GAUSSIAN_WG
from ..render.renderer import RenderResult
from ..runtime import BUFFER_GROWTH, Runtime

PIXELGS_DEPTH_FRACTION = 0.37   # Pixel-GS: gradients of Gaussians nearer than this x extent are scaled down
TRACK_MIN_VIEWS = 5             # DCS: split costs for every Gaussian in its first views of a window


BASE_COLUMNS = ("grad", "abs", "views", "pix_grad", "pix", "max_radius")
DCC_COLUMNS = ("dcc_abs", "dcc_grad", "dcc_pix")
DC_WINDOW_COLUMNS = ("dc_ux", "dc_uy", "dc_n")


@dataclass(frozen=True)
class WindowLayout:
    """Per-Gaussian window accumulators (see kernels/densify_stats.cl): the base columns; with dc the DCC
    terms (and, pooled over the window, the running unit-vector sums); with split_candidates N the split
    costs J (N), and, pooled over the window, the sides' running sums: totals (5) and left sums (5 N)."""
    dc: bool = False
    split_candidates: int = 0
    window_pooling: bool = False
    criterion: tuple[str, str] = ("grad", "views")   # the split criterion's (total, count) columns

    @property
    def columns(self) -> dict[str, tuple[int, int]]:
        """name -> (offset, width)."""
        widths = [(k, 1) for k in BASE_COLUMNS]
        if self.dc:
            widths += [(k, 1) for k in DCC_COLUMNS]
            if self.window_pooling:
                widths += [(k, 1) for k in DC_WINDOW_COLUMNS]
        if self.split_candidates:
            widths += [("j", self.split_candidates), ("skip_split", 1)]
            if self.window_pooling:
                widths += [("total", 5), ("left", 5 * self.split_candidates)]
        out, at = {}, 0
        for name, w in widths:
            out[name] = (at, w)
            at += w
        return out

    @property
    def width(self) -> int:
        return sum(w for _, w in self.columns.values())

    def defines(self) -> dict[str, int]:
        cols = self.columns
        return {"WINDOW_WIDTH": self.width, "DC_WINDOW": int(self.window_pooling),
                "TRACK_TOTAL": cols[self.criterion[0]][0], "TRACK_COUNT": cols[self.criterion[1]][0],
                "TRACK_MIN_VIEWS": TRACK_MIN_VIEWS, **{f"WIN_{k.upper()}": at for k, (at, _) in cols.items()}}


class WindowStats:
    def __init__(self, rt: Runtime, sums_layout: SumsLayout, extent: float, layout: WindowLayout = WindowLayout(),
                 track_threshold: float = 0.0):
        self.rt, self.layout, self.sums_layout = rt, layout, sums_layout
        self.track_threshold = track_threshold
        if layout.dc != sums_layout.dc_stats or layout.split_candidates != sums_layout.split_candidates:
            raise ValueError("the window's DC4GS columns must match the backward's sums")
        self.depth_scale = PIXELGS_DEPTH_FRACTION * extent
        self.kernel = rt.kernel("densify_stats.cl", "accumulate_view_stats",
                                {**sums_layout.defines(), **layout.defines()})
        self.buffer: cl.Buffer | None = None
        self.n = 0

    def reset(self, n: int) -> None:
        """Zero the accumulators for n Gaussians (after densification, or at the start)."""
        nbytes = 4 * self.layout.width * max(n, 1)
        if self.buffer is None or self.buffer.size < nbytes:
            self.buffer = self.rt.buffer(int(nbytes * BUFFER_GROWTH))
        self.rt.fill(self.buffer, np.float32(0), 4 * self.layout.width * n)
        self.n = n

    def accumulate(self, res: RenderResult, sums: cl.Buffer, split_geometry: cl.Buffer | None = None) -> None:
        n = self.n
        if n == 0:
            return
        self.rt.launch_items("densify_stats", self.kernel, n, PER_GAUSSIAN_WG, np.uint32(n),
                       np.float32(0.5 * res.width), np.float32(0.5 * res.height), np.float32(self.depth_scale),
                       np.float32(self.track_threshold), res.proj.radius, res.proj.depth, sums, split_geometry if split_geometry is not None else sums,
                       self.buffer)

    def download(self) -> dict[str, np.ndarray]:
        """name -> (n,) or (n, width) arrays."""
        a = self.rt.to_host(self.buffer, (self.n, self.layout.width))
        return {k: a[:, at] if w == 1 else a[:, at:at + w] for k, (at, w) in self.layout.columns.items()}

    def upload(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore accumulators (resuming a run)."""
        n = len(next(iter(arrays.values())))
        self.reset(n)
        cols = [np.asarray(arrays[k], np.float32).reshape(n, w) for k, (_, w) in self.layout.columns.items()]
        self.rt.write(self.buffer, np.concatenate(cols, 1))
