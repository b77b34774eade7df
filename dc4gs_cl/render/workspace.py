"""Named device buffers that grow (by half again) and are otherwise reused across frames."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..runtime import BUFFER_GROWTH, Runtime

POISON = np.uint32(0x7FC00001)   # a NaN as float32, a huge count as uint32


class Workspace:
    def __init__(self, rt: Runtime, poison: bool = False):
        """poison: fill every new buffer with POISON, so that a value a kernel failed to write shows up."""
        self.rt, self.poison = rt, poison
        self._buffers: dict[str, cl.Buffer] = {}

    def get(self, name: str, nbytes: int) -> cl.Buffer:
        buf = self._buffers.get(name)
        if buf is None or buf.size < nbytes:
            size = max(int(nbytes), int(buf.size * BUFFER_GROWTH) if buf is not None else 0, 64)
            buf = self._buffers[name] = self.rt.buffer(size)
            if self.poison:
                self.rt.fill(buf, POISON, buf.size)
        return buf
