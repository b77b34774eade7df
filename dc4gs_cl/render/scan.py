"""Exclusive prefix sum of uint32 on the device (kernels/scan.cl), a reusable primitive."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from .stage import Stage, StageContext


class ExclusiveScan(Stage):
    """out[i] = sum(in[:i]); the grand total goes to total[total_at]. flags=True scans (in != 0)."""
    FILE, KERNELS = "scan.cl", ("scan_reduce", "scan_sums", "scan_apply")

    def __init__(self, ctx: StageContext, flags: bool = False):
        super().__init__(ctx)
        self.flags = flags
        self.wg, self.max_groups = ctx.tuning.scan_wg, ctx.tuning.scan_groups
        self.block_sums = self.rt.buffer(4 * self.max_groups)
        k = self.kernels()
        self.k_reduce, self.k_sums, self.k_apply = k["scan_reduce"], k["scan_sums"], k["scan_apply"]

    def defines(self) -> dict:
        return {"SCAN_WG": self.wg, "SCAN_FLAGS": int(self.flags)}

    def __call__(self, src: cl.Buffer, dst: cl.Buffer, n: int, total: cl.Buffer, total_at: int = 0,
                 stage: str = "scan") -> None:
        rt = self.rt
        if n == 0:
            cl.enqueue_fill_buffer(rt.queue, total, np.uint32(0), 4 * total_at, 4)
            return
        items_wanted = self.max_groups * self.wg
        item_len = -(-n // items_wanted)
        groups = -(-n // (item_len * self.wg))
        g = groups * self.wg
        rt.launch(stage, self.k_reduce, g, self.wg, np.uint32(n), np.uint32(item_len), src, self.block_sums)
        rt.launch(stage, self.k_sums, 1, 1, np.uint32(groups), self.block_sums, total, np.uint32(total_at))
        rt.launch(stage, self.k_apply, g, self.wg, np.uint32(n), np.uint32(item_len), src, dst, self.block_sums)
