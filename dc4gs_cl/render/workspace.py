"""Named scratch buffers on the device, reused from frame to frame and grown (runtime.grown_size) when a
frame needs more."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..runtime import Runtime, grown_size

POISON = np.uint32(0x7FC00001)   # a NaN as float32, a huge count as uint32
MIN_BYTES = 64


class Workspace:
    def __init__(self, rt: Runtime, poison: bool = False):
        """poison: fill every new buffer with POISON, so that a value a kernel failed to write shows up."""
        self.rt, self.poison = rt, poison
        self._buffers: dict[str, cl.Buffer] = {}

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

    def held(self) -> dict[str, int]:
        """Bytes held per buffer name (for memory reports)."""
        return {name: buf.size for name, buf in self._buffers.items()}
