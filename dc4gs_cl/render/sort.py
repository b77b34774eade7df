"""Stable LSD radix sort of uint32 keys with uint32 values on the device (kernels/sort.cl): three launches
per pass (histogram, spine, scatter), in the shape Tuning.sort_wg picks (runs walked per work-item, or ranked in
local memory per work-group).

Only the key bits [bit_lo, bit_hi) are sorted: callers pass the range in which keys can differ, so
no pass is spent on bits that are always equal (the top tile bits, a depth key's sign bit).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from .scan import device_count
from .stage import Stage, StageContext, halvings

KEYS_PER_ITEM = 4   # the ranked shape (sort_wg > 1): keys per work-item in a tile (Brush's 4 keys x 256 items)


def digit_plan(bit_lo: int, bit_hi: int, radix_bits: int) -> list[tuple[int, int]]:
    """(shift, digit_bits) of each pass: as few passes as the widest digit allows, digits balanced."""
    nbits = max(0, bit_hi - bit_lo)
    if nbits == 0:
        return []
    passes = -(-nbits // radix_bits)
    width = -(-nbits // passes)
    plan, shift = [], bit_lo
    while shift < bit_hi:
        bits = min(width, bit_hi - shift)
        plan.append((shift, bits))
        shift += bits
    return plan


class RadixSort(Stage):
    FILE, KERNELS = "sort.cl", ("radix_histogram", "radix_spine", "radix_scatter")

    def __init__(self, ctx: StageContext):
        super().__init__(ctx)
        self.tuning = ctx.tuning
        self.wg, k = self.fitted(ctx.tuning.sort_wg)
        self.k_hist, self.k_spine, self.k_scatter = k["radix_histogram"], k["radix_spine"], k["radix_scatter"]

    def defines(self) -> dict:
        return {"RADIX_BITS": self.tuning.radix_bits}

    def fitted(self, wg: int) -> tuple[int, dict[str, cl.Kernel]]:
        """The ranked shape's widest work-group, Tuning.sort_wg halved as needed, whose kernels the device runs
        (its work-group limit for them, its local memory for the tile); 1 (runs per work-item) where none."""
        rt = self.rt
        for w in halvings(wg):
            k = self.kernels({"SORT_WG": w, **({"KEYS_PER_ITEM": KEYS_PER_ITEM} if w > 1 else {})})
            if w == 1 or (all(rt.kernel_limits(k[name]).work_group >= w for name in self.KERNELS)
                          and rt.kernel_limits(k["radix_scatter"]).local_bytes <= rt.caps.local_mem_size):
                return w, k
        raise AssertionError("unreachable: halvings end at 1")

    def runs(self, n: int) -> int:
        """The runs the keys are cut into for at most n keys: at most Tuning.sort_blocks, in the ranked shape at
        most one per tile of wg * KEYS_PER_ITEM keys (the kernels cut the keys there are into these runs)."""
        return min(self.tuning.sort_blocks, -(-n // (self.wg * KEYS_PER_ITEM if self.wg > 1 else 1)))

    def __call__(self, keys: cl.Buffer, vals: cl.Buffer, n: int, bit_lo: int = 0, bit_hi: int = 32,
                 stage: str = "sort", count: cl.Buffer | None = None, count_at: int = 0,
                 scratch: tuple[cl.Buffer, cl.Buffer] | None = None) -> tuple[cl.Buffer, cl.Buffer]:
        """Sort n (key, value) pairs by key bits [bit_lo, bit_hi), or, with `count`, the first count[count_at]
        (the count the device wrote; n, the bound, sizes the launches and buffers), so that the host reads nothing
        back first. scratch: buffers of n keys and n values that the passes alternate with (default: workspace
        buffers). Returns the buffers holding the result: the inputs themselves or the scratch ones (which later
        calls may overwrite)."""
        plan = digit_plan(bit_lo, bit_hi, self.tuning.radix_bits) if n > 1 else []
        if not plan:
            return keys, vals
        rt, wg = self.rt, self.wg
        blocks = self.runs(n)
        spine = (1 << self.tuning.radix_bits) * blocks
        hist = self.ws.get("sort.hist", 4 * spine)
        src = (keys, vals)
        dst = scratch or (self.ws.get("sort.keys", 4 * n), self.ws.get("sort.vals", 4 * n))
        counted = device_count(n, count, count_at, hist)
        for shift, bits in plan:
            args = (*counted, np.uint32(shift), np.uint32((1 << bits) - 1))
            rt.launch(stage, self.k_hist, blocks * wg, wg if wg > 1 else None, *args, src[0], hist)
            rt.launch(stage, self.k_spine, wg, wg, np.uint32(spine), hist)
            rt.launch(stage, self.k_scatter, blocks * wg, wg if wg > 1 else None, *args, src[0], src[1], hist,
                      dst[0], dst[1])
            src, dst = dst, src
        return src
