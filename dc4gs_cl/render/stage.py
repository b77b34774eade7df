"""The one shape of every stage host, and what the stages of one pipeline share.

A stage host is a class named after its kernel file (project.cl -> Project): made once, called once per
frame. It builds its kernels once per variant it meets (a variant: the -D options that change between
calls, such as the SH coefficient count or the backward's sums layout) and keeps the Kernel objects, so
nothing is looked up or rebuilt on the hot path. The forward stages (render/) and the backward stages
(backward/) of one trainer share a StageContext: the runtime, the work shapes, the algorithm switches,
the workspace of scratch buffers, the --check-finite switch and the last frame's counts.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..constants import FRAME_WORDS
from ..errors import DeviceError
from ..finite import FiniteCheck
from ..runtime import HostRead, Runtime
from .options import RenderOptions
from .tuning import Tuning
from .workspace import Workspace

PER_GAUSSIAN_WG = 64   # work-group size of the kernels with one work-item per Gaussian


class StageContext:
    def __init__(self, rt: Runtime, tuning: Tuning | None = None, options: RenderOptions | None = None,
                 poison: bool = False, check_finite: bool = False):
        """poison: fill every new scratch buffer with NaN (tests: a value a kernel failed to write shows up).
        check_finite: every stage checks its outputs (finite.FiniteCheck)."""
        self.rt = rt
        self.tuning = tuning or Tuning.for_device(rt.caps)
        self.options = options or RenderOptions()
        self.ws = Workspace(rt, poison)
        self.check = FiniteCheck(check_finite)
        # the last frame's counts (constants.FRAME_WORDS; render/isect.py): zero, a valid frame, until one is made
        self.frame = rt.buffer(4 * len(FRAME_WORDS))
        rt.fill(self.frame, np.uint32(0), self.frame.size)

    def frame_counts(self) -> dict[str, int]:
        """The last frame's counts, read back (a blocking read): constants.FRAME_WORDS, each word's value."""
        return self.frame_counts_later().result()

    def frame_counts_later(self) -> "FrameCounts":
        """The frame's counts as the queue stands, read without waiting: FrameCounts.result() waits for them."""
        return FrameCounts(self.rt.to_host_later(self.frame, len(FRAME_WORDS), np.uint32))


class FrameCounts:
    """A frame's counts queued for reading (StageContext.frame_counts_later)."""

    def __init__(self, read: HostRead):
        self.read = read

    def result(self) -> dict[str, int]:
        """constants.FRAME_WORDS, each word's value (waits for the read: a blocking sync, the first time)."""
        return dict(zip(FRAME_WORDS, map(int, self.read.result())))


class Stage:
    FILE: str                      # kernels/<FILE>
    KERNELS: tuple[str, ...]       # the kernels of that file this stage launches

    def __init__(self, ctx: StageContext):
        self.ctx, self.rt, self.ws = ctx, ctx.rt, ctx.ws
        self._built: dict[tuple, dict[str, cl.Kernel]] = {}
        self._batch_fitted: dict[tuple, dict[str, cl.Kernel]] = {}

    def defines(self) -> dict:
        """The -D options fixed for this stage's life (work shapes, switches); variants add to them."""
        return {}

    def language(self, variant: dict) -> str:
        """The OpenCL C version a variant is built as."""
        return "CL1.2"

    def kernels(self, variant: dict | None = None) -> dict[str, cl.Kernel]:
        """This stage's kernels for a variant, built the first time it is asked for."""
        key = tuple(sorted((variant or {}).items()))
        built = self._built.get(key)
        if built is None:
            defines = {**self.defines(), **(variant or {})}
            program = self.rt.program(self.FILE, defines, self.language(defines))
            built = self._built[key] = {name: cl.Kernel(program, name) for name in self.KERNELS}
        return built

    def fitting_kernels(self, variants: list[dict], kernel: str) -> tuple[dict, dict[str, cl.Kernel]]:
        """The first of these variants (the preferred shape first, then smaller ones) whose built `kernel` fits
        the device's local memory, as its driver reports it, and that variant's kernels. DeviceError if none."""
        limit = self.rt.caps.local_mem_size
        for variant in variants:
            built = self.kernels(variant)
            needed = self.rt.kernel_limits(built[kernel]).local_bytes
            if needed <= limit:
                return variant, built
        raise DeviceError(f"kernels/{self.FILE}: {kernel} needs {needed:,} bytes of local memory even in its "
                          f"smallest shape; the device has {limit:,}")

    def batch_fitted_kernels(self, variant: dict, kernel: str) -> dict[str, cl.Kernel]:
        """The rasterizers' kernels for a variant with the largest BATCH (Gaussians held in local memory at a time:
        the tuning's, halved as needed) whose `kernel` fits the device's local memory; kept per variant."""
        key = tuple(sorted(variant.items()))
        if key not in self._batch_fitted:
            self._batch_fitted[key] = self.fitting_kernels(
                [{**variant, "BATCH": b, **self.with_batch(variant, b)} for b in halvings(self.ctx.tuning.batch)],
                kernel)[1]
        return self._batch_fitted[key]

    def with_batch(self, variant: dict, batch: int) -> dict:
        """-D options that shrink with the batch (none here)."""
        return {}

    def check(self, arrays) -> None:
        """--check-finite: `arrays()` gives the host copies of this call's outputs; read only when on."""
        if self.ctx.check.enabled:
            self.ctx.check(self.FILE.removesuffix(".cl"), arrays())


def halvings(size: int) -> list[int]:
    """size, size // 2, ..., 1: the shapes a stage tries, largest first, to fit a device's limits."""
    return [size >> k for k in range(size.bit_length())]


def visible_rows(rt: Runtime, buf: cl.Buffer, radius: np.ndarray, width: int) -> np.ndarray:
    """The rows of a per-Gaussian (N, width) float32 buffer that belong to Gaussians visible in the view
    (radius > 0): the only rows a view's stage defines."""
    return rt.to_host(buf, (len(radius), width))[radius > 0]
