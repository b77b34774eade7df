"""Densification statistics on the device: each view's per-Gaussian sums folded into accumulators that
live until the next densification step (kernels/densify_stats.cl). The host reads them only there."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..render.backward import SumsLayout
from ..render.renderer import RenderResult
from ..runtime import Runtime

STATS_WG = 64
PIXELGS_DEPTH_FRACTION = 0.37   # Pixel-GS: gradients of Gaussians nearer than this x extent are scaled down


@dataclass(frozen=True)
class WindowLayout:
    """Per-Gaussian window accumulators, in this order (see kernels/densify_stats.cl)."""
    names: tuple[str, ...] = ("grad", "abs", "views", "pix_grad", "pix", "max_radius")

    @property
    def width(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def defines(self) -> dict[str, int]:
        return {"WINDOW_WIDTH": self.width, **{f"WIN_{k.upper()}": i for i, k in enumerate(self.names)}}


class WindowStats:
    def __init__(self, rt: Runtime, sums_layout: SumsLayout, extent: float, layout: WindowLayout = WindowLayout()):
        self.rt, self.layout, self.sums_layout = rt, layout, sums_layout
        self.depth_scale = PIXELGS_DEPTH_FRACTION * extent
        self.kernel = rt.kernel("densify_stats.cl", "accumulate_view_stats",
                                {**sums_layout.defines(), **layout.defines()})
        self.buffer: cl.Buffer | None = None
        self.n = 0

    def reset(self, n: int) -> None:
        """Zero the accumulators for n Gaussians (after densification, or at the start)."""
        nbytes = 4 * self.layout.width * max(n, 1)
        if self.buffer is None or self.buffer.size < nbytes:
            self.buffer = self.rt.buffer(int(nbytes * 1.5))
        self.rt.fill(self.buffer, np.float32(0), 4 * self.layout.width * n)
        self.n = n

    def accumulate(self, res: RenderResult, sums: cl.Buffer) -> None:
        n = self.n
        if n == 0:
            return
        self.rt.launch("densify_stats", self.kernel, -(-n // STATS_WG) * STATS_WG, STATS_WG, np.uint32(n),
                       np.float32(0.5 * res.width), np.float32(0.5 * res.height), np.float32(self.depth_scale),
                       res.proj.radius, res.proj.depth, sums, self.buffer)

    def download(self) -> dict[str, np.ndarray]:
        a = self.rt.to_host(self.buffer, (self.n, self.layout.width))
        return {k: a[:, i] for i, k in enumerate(self.layout.names)}

    def upload(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore accumulators (resuming a run)."""
        n = len(next(iter(arrays.values())))
        self.reset(n)
        self.rt.write(self.buffer, np.stack([arrays[k] for k in self.layout.names], 1).astype(np.float32))
