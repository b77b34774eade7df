"""Named scratch buffers on the device, reused from frame to frame and grown (runtime.grown_size) when a
frame needs more."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..runtime import Runtime, grown_size

POISON = np.uint32(0x7FC00001)   # a NaN as float32, a huge count as uint32
MIN_BYTES = 64
# The pool of a frame's temporaries that are never alive together (Workspace.scratch): the intersection's
# emission arrays and tile sort, then the loss' images, then the backward's per-pair slots.
PAIR_SCRATCH = "pairs.scratch"


class Workspace:
    def __init__(self, rt: Runtime, poison: bool = False):
        """poison: fill every new buffer with POISON, so that a value a kernel failed to write shows up."""
        self.rt, self.poison = rt, poison
        self._buffers: dict[str, cl.Buffer] = {}
        # sub-buffers start at multiples of the device's base address alignment (bits)
        self._align = max(16, rt.device.mem_base_addr_align // 8)

    def get(self, name: str, nbytes: int) -> cl.Buffer:
        """The buffer `name`, at least nbytes; its contents are whatever the last user left (or POISON)."""
        buf = self._buffers.get(name)
        if buf is None or buf.size < nbytes:
            have = buf.size if buf is not None else 0
            # Growing keeps no contents, so the old buffer goes first: the two are never held together.
            buf = self._buffers[name] = None
            buf = self._buffers[name] = self.rt.buffer(grown_size(max(int(nbytes), MIN_BYTES), have))
            if self.poison:
                self.rt.fill(buf, POISON, buf.size)
        return buf

    def scratch(self, pool: str, parts: dict[str, int]) -> dict[str, cl.Buffer]:
        """Buffers of these sizes (name -> bytes), laid out one after another in the buffer `pool` (grown to hold
        them): temporaries whose owner is done with them before the pool's next user asks, as each call lays its
        parts out from the pool's start, over the last call's. So one allocation serves stages whose temporaries are
        never alive together, and holds the largest of them, not their sum. The caller lets go of the parts within
        its call (a part kept would hold the pool on the device past its growth)."""
        offsets, end = {}, 0
        for name, nbytes in parts.items():
            size = max(int(nbytes), MIN_BYTES)
            offsets[name] = (end, size)
            end += -(-size // self._align) * self._align
        buf = self.get(pool, end)
        # (sub-buffers made afresh, a few per frame: each one holds its pool on the device, so none is kept here)
        return {name: buf.get_sub_region(*region) for name, region in offsets.items()}

    def held(self) -> dict[str, int]:
        """Bytes held per buffer name (for memory reports)."""
        return {name: buf.size for name, buf in self._buffers.items()}
