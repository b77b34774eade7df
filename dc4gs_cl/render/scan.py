"""Exclusive prefix sum of uint32 on the device (kernels/scan.cl), a reusable primitive."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..constants import HOST_COUNT
from .stage import Stage, StageContext


class ExclusiveScan(Stage):
    """out[i] = sum(in[:i]); the grand total goes to total[total_at]. flags=True scans (in != 0); gather=True
    scans in[order[i]] (order given at each call)."""
    FILE, KERNELS = "scan.cl", ("scan_reduce", "scan_apply")

    def __init__(self, ctx: StageContext, flags: bool = False, gather: bool = False):
        super().__init__(ctx)
        self.flags, self.gather = flags, gather
        self.wg, self.max_groups = ctx.tuning.scan_wg, ctx.tuning.scan_groups
        self.block_sums = self.rt.buffer(4 * self.max_groups)
        k = self.kernels()
        self.k_reduce, self.k_apply = k["scan_reduce"], k["scan_apply"]

    def defines(self) -> dict:
        return {"SCAN_WG": self.wg, "SCAN_FLAGS": int(self.flags), "SCAN_GATHER": int(self.gather)}

    def __call__(self, src: cl.Buffer, dst: cl.Buffer, n: int, total: cl.Buffer, total_at: int = 0,
                 stage: str = "scan", count: cl.Buffer | None = None, count_at: int = 0,
                 order: cl.Buffer | None = None) -> None:
        """Scan n elements, or, with `count`, as many as count[count_at] says on the device (n, the bound,
        sizes the launch), so that the host reads nothing back first. order: [n] uint, with gather=True."""
        if (order is None) == self.gather:
            raise ValueError("a gathering scan takes an order, and only it")
        rt = self.rt
        if n == 0:
            cl.enqueue_fill_buffer(rt.queue, total, np.uint32(0), 4 * total_at, 4)
            return
        items_wanted = self.max_groups * self.wg
        item_len = -(-n // items_wanted)
        groups = -(-n // (item_len * self.wg))
        g = groups * self.wg
        counted = device_count(n, count, count_at, self.block_sums)
        gathered = [order] if self.gather else []
        rt.launch(stage, self.k_reduce, g, self.wg, *counted, src, self.block_sums, *gathered)
        rt.launch(stage, self.k_apply, g, self.wg, *counted, src, dst, self.block_sums, total, np.uint32(total_at),
                  *gathered)


def device_count(bound: int, count: cl.Buffer | None, count_at: int, placeholder: cl.Buffer) -> tuple:
    """The (bound, count, count_at) arguments of a kernel that takes its element count from runs.h's
    element_count: `bound` alone where count is None (placeholder: any buffer, never read)."""
    if count is None:
        return np.uint32(bound), placeholder, np.uint32(HOST_COUNT)
    return np.uint32(bound), count, np.uint32(count_at)
