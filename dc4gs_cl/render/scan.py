"""Exclusive prefix sum of uint32 on the device (kernels/scan.cl)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..runtime import Runtime
from .tuning import Tuning


class ExclusiveScan:
    """out[i] = sum(in[:i]); the grand total goes to total[total_at]. flags=True scans (in != 0)."""

    def __init__(self, rt: Runtime, tuning: Tuning, flags: bool = False):
        self.rt, self.wg, self.max_groups = rt, tuning.scan_wg, tuning.scan_groups
        defines = {"SCAN_WG": self.wg, "SCAN_FLAGS": int(flags)}
        self.k_reduce = rt.kernel("scan.cl", "scan_reduce", defines)
        self.k_sums = rt.kernel("scan.cl", "scan_sums", defines)
        self.k_apply = rt.kernel("scan.cl", "scan_apply", defines)
        self.block_sums = rt.buffer(4 * self.max_groups)

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
