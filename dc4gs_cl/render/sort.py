"""Stable LSD radix sort of uint32 keys with uint32 values on the device (kernels/sort.cl).

Only the key bits [bit_lo, bit_hi) are sorted: callers pass the range in which keys can differ, so
no pass is spent on bits that are always equal (the top tile bits, the constant high bits of depths).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from .scan import ExclusiveScan
from .stage import Stage, StageContext


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
    FILE, KERNELS = "sort.cl", ("radix_histogram", "radix_scatter")

    def __init__(self, ctx: StageContext):
        super().__init__(ctx)
        self.tuning = ctx.tuning
        k = self.kernels()
        self.k_hist, self.k_scatter = k["radix_histogram"], k["radix_scatter"]
        self.scan = ExclusiveScan(ctx)
        self.scratch_total = self.rt.buffer(4)

    def defines(self) -> dict:
        return {"RADIX_BITS": self.ctx.tuning.radix_bits}

    def __call__(self, keys: cl.Buffer, vals: cl.Buffer, n: int, bit_lo: int = 0, bit_hi: int = 32,
                 stage: str = "sort") -> tuple[cl.Buffer, cl.Buffer]:
        """Sort n (key, value) pairs by key bits [bit_lo, bit_hi). Returns the buffers holding the result:
        the inputs themselves or workspace buffers (which later calls may overwrite)."""
        plan = digit_plan(bit_lo, bit_hi, self.tuning.radix_bits) if n > 1 else []
        if not plan:
            return keys, vals
        rt = self.rt
        blocks = min(self.tuning.sort_blocks, n)
        block_len = -(-n // blocks)
        blocks = -(-n // block_len)
        radix = 1 << self.tuning.radix_bits
        hist = self.ws.get("sort.hist", 4 * radix * blocks)
        src = (keys, vals)
        dst = (self.ws.get("sort.keys", 4 * n), self.ws.get("sort.vals", 4 * n))
        for shift, bits in plan:
            args = (np.uint32(n), np.uint32(block_len), np.uint32(shift), np.uint32((1 << bits) - 1))
            rt.launch(stage, self.k_hist, blocks, None, *args, src[0], hist)
            self.scan(hist, hist, radix * blocks, self.scratch_total, 0, stage=stage)
            rt.launch(stage, self.k_scatter, blocks, None, *args, src[0], src[1], hist, dst[0], dst[1])
            src, dst = dst, src
        return src
