"""OpenCL runtime: device choice, context and queue, the program registry, per-stage profiling.

One `Runtime` per process and device. Programs are built once per (kernel file, -D options) (PoCL and
pyopencl also keep compiled binaries on disk, so a new process builds fast); the stage hosts keep their
`Kernel` objects (render/stage.py), so nothing is rebuilt or looked up on the hot path. `#include "x.h"`
lines in kernel files are resolved here, textually (generated headers included), so the source text alone
decides what the driver caches. Every device buffer
is made here (`buffer`, `to_device`), which counts the bytes held (`memory_in_use`) and their
high-water mark (`memory_peak`, restarted by `reset_memory_peak()`).
"""
from __future__ import annotations

import os
import re
import weakref
from collections import defaultdict
from dataclasses import dataclass
from importlib import resources

import numpy as np
import pyopencl as cl

from .constants import kernel_defines
from .errors import DeviceError
from .records import records_header

DEVICE_ENV = "DC4GS_DEVICE"   # same forms as --device: "P:D", "gpu", "cpu" or part of the name
RELAXED_MATH = "RELAXED_MATH"  # a define that, set to 1, also builds the program with -cl-fast-relaxed-math
BUFFER_GROWTH = 1.5           # a buffer that must grow gets this much more than it had: fewer reallocations

_INCLUDE = re.compile(r'^\s*#\s*include\s+"([\w.]+)"\s*$', re.M)


def generated_headers() -> dict[str, str]:
    """Headers written by the host rather than kept as files: records.h, the structs of records.py."""
    return {"records.h": records_header()}


def kernel_source(name: str) -> str:
    """Text of kernels/<name> with its local #include lines replaced by the headers' text (generated
    headers included), so that the text alone decides what the driver caches."""
    root = resources.files("dc4gs_cl") / "kernels"
    generated = generated_headers()

    def expand(text: str, seen: tuple[str, ...]) -> str:
        def sub(m: re.Match) -> str:
            header = m.group(1)
            if header in seen:
                return ""
            body = generated[header] if header in generated else (root / header).read_text()
            return expand(body, seen + (header,))
        return _INCLUDE.sub(sub, text)

    return expand((root / name).read_text(), (name,))


def grown_size(want: int, have: int) -> int:
    """What a buffer (or array capacity) that holds `have` and must hold `want` grows to: at least
    BUFFER_GROWTH x what it had, so that a growing model reallocates rarely. The one growth rule."""
    return want if want <= have else max(want, int(have * BUFFER_GROWTH))


def list_devices() -> list[tuple[str, cl.Device]]:
    """Every OpenCL device as ("P:D", device). Raises DeviceError when no platform exists."""
    try:
        platforms = cl.get_platforms()
    except cl.Error as e:
        platforms, why = [], str(e)
    else:
        why = "no platform reported a device"
    out = []
    for pi, p in enumerate(platforms):
        try:
            devices = p.get_devices()
        except cl.Error:
            continue
        out += [(f"{pi}:{di}", d) for di, d in enumerate(devices)]
    if not out:
        raise DeviceError("No OpenCL device found (" + why + "). Install PoCL for the CPU with "
                          "`pip install 'pyopencl[pocl]'`, or a GPU vendor's OpenCL driver.")
    return out


def describe(device: cl.Device) -> str:
    kind = next((name for name, bit in (("GPU", cl.device_type.GPU), ("CPU", cl.device_type.CPU),
                                        ("accelerator", cl.device_type.ACCELERATOR)) if device.type & bit), "other")
    return f"{device.platform.name.strip()} | {device.name.strip()} ({kind}, {device.max_compute_units} compute units)"


def choose_device(spec: str | None = None) -> tuple[str, cl.Device]:
    """The device named by `spec` (or $DC4GS_DEVICE): "P:D" indices, "gpu", "cpu", or a case-insensitive
    part of "platform | device". With neither, the first GPU, else the first CPU, else the first device."""
    devices = list_devices()
    spec = spec if spec is not None else os.environ.get(DEVICE_ENV) or None
    if spec is None:
        for want in (cl.device_type.GPU, cl.device_type.CPU):
            for key, d in devices:
                if d.type & want:
                    return key, d
        return devices[0]
    s = spec.strip().lower()
    for key, d in devices:
        if s == key:
            return key, d
    kinds = {"gpu": cl.device_type.GPU, "cpu": cl.device_type.CPU, "accelerator": cl.device_type.ACCELERATOR}
    for key, d in devices:
        if (s in kinds and d.type & kinds[s]) or (s not in kinds and s in describe(d).lower()):
            return key, d
    names = "; ".join(f"{k} {describe(d)}" for k, d in devices)
    raise DeviceError(f"no OpenCL device matches '{spec}' (devices: {names})")


@dataclass(frozen=True)
class Capabilities:
    is_cpu: bool
    compute_units: int
    max_work_group_size: int
    local_mem_size: int
    float_atomic_add: bool     # native float atomics (cl_ext_float_atomics); our kernels need none (see
                               # kernels/common.h), this is reported by `dc4gs-cl devices`
    fp64: bool

    @staticmethod
    def of(device: cl.Device) -> "Capabilities":
        ext = device.extensions.split()
        return Capabilities(
            is_cpu=bool(device.type & cl.device_type.CPU),
            compute_units=device.max_compute_units,
            max_work_group_size=device.max_work_group_size,
            local_mem_size=device.local_mem_size,
            float_atomic_add="cl_ext_float_atomics" in ext,
            fp64="cl_khr_fp64" in ext,
        )

    def summary(self) -> str:
        return (f"work-groups up to {self.max_work_group_size}, {self.local_mem_size // 1024} KiB local memory, "
                f"float atomics: {'native' if self.float_atomic_add else 'none (compare-and-swap emulation)'}, "
                f"fp64: {'yes' if self.fp64 else 'no'}")


class _Buffer(cl.Buffer):
    """A cl.Buffer that can be weakly referenced (pyopencl's cannot), so that its release can be counted."""


def _format_define(v) -> str:
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return f"{v!r}f"
    return str(v)


class Runtime:
    """Context, in-order queue and the program registry for one device."""

    def __init__(self, device: str | None = None, profiling: bool = False):
        self.device_key, self.device = choose_device(device)
        self.context = cl.Context([self.device])
        props = cl.command_queue_properties.PROFILING_ENABLE if profiling else 0
        self.queue = cl.CommandQueue(self.context, properties=props)
        self.profiling = profiling
        self.caps = Capabilities.of(self.device)
        self._programs: dict[tuple, cl.Program] = {}
        self.events: dict[str, list[cl.Event]] = defaultdict(list)
        self.memory_in_use = 0   # bytes in device buffers made here and not yet released
        self.memory_peak = 0     # the most memory_in_use has been since the last reset_memory_peak()

    def __repr__(self) -> str:
        return f"Runtime({self.device_key} {describe(self.device)})"

    # programs -----------------------------------------------------------------------------------
    def build_options(self, defines: dict | None = None) -> list[str]:
        merged = {k: _format_define(v) for k, v in {**kernel_defines(), **(defines or {})}.items()}
        flags = ["-cl-fast-relaxed-math"] if merged.get(RELAXED_MATH) == "1" else []
        return [f"-D{k}={v}" for k, v in sorted(merged.items())] + ["-cl-std=CL1.2"] + flags

    def program(self, file: str, defines: dict | None = None) -> cl.Program:
        key = (file, tuple(sorted((defines or {}).items())))
        prg = self._programs.get(key)
        if prg is None:
            options = self.build_options(defines)
            try:
                prg = cl.Program(self.context, kernel_source(file)).build(options=options)
            except cl.RuntimeError as e:
                raise DeviceError(f"building kernels/{file} with {' '.join(options)} failed:\n{e}") from None
            self._programs[key] = prg
        return prg

    # launches and buffers -----------------------------------------------------------------------
    def launch(self, stage: str, kernel: cl.Kernel, global_size, local_size, *args) -> cl.Event:
        """Enqueue a kernel; with profiling on, its event is kept under `stage`."""
        if isinstance(global_size, int):
            global_size = (global_size,)
        if isinstance(local_size, int):
            local_size = (local_size,)
        ev = kernel(self.queue, global_size, local_size, *args)
        if self.profiling:
            self.events[stage].append(ev)
        return ev

    def launch_items(self, stage: str, kernel: cl.Kernel, n: int, wg: int, *args) -> cl.Event:
        """A 1D launch of n work-items (one per element) in work-groups of wg: the global size is n rounded
        up, so the kernel must bound-check its index against n."""
        return self.launch(stage, kernel, -(-n // wg) * wg, wg, *args)

    def stage_times(self, reset: bool = True) -> dict[str, float]:
        """Seconds of device time per stage since the last reset (waits for the queue)."""
        self.queue.finish()
        out = {s: sum((e.profile.end - e.profile.start) * 1e-9 for e in evs) for s, evs in self.events.items()}
        if reset:
            self.events.clear()
        return out

    def buffer(self, nbytes: int) -> cl.Buffer:
        """A device buffer of at least nbytes, rounded up to 16 bytes (fills use 4-byte patterns)."""
        return self._counted(_Buffer(self.context, cl.mem_flags.READ_WRITE, max(-(-int(nbytes) // 16) * 16, 16)))

    def to_device(self, array: np.ndarray) -> cl.Buffer:
        a = np.ascontiguousarray(array)
        if not a.nbytes:
            return self.buffer(4)
        return self._counted(_Buffer(self.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a))

    # memory accounting: bytes are added when a buffer is made and taken off when Python releases it
    def _counted(self, buf: _Buffer) -> _Buffer:
        self.memory_in_use += buf.size
        self.memory_peak = max(self.memory_peak, self.memory_in_use)
        weakref.finalize(buf, self._released, buf.size)
        return buf

    def _released(self, nbytes: int) -> None:
        self.memory_in_use -= nbytes

    def reset_memory_peak(self) -> None:
        """Start a new high-water mark from what is allocated now."""
        self.memory_peak = self.memory_in_use

    def to_host(self, buf: cl.Buffer, shape, dtype=np.float32) -> np.ndarray:
        out = np.empty(shape, dtype=dtype)
        if out.nbytes:
            cl.enqueue_copy(self.queue, out, buf)
        return out

    def write(self, buf: cl.Buffer, array: np.ndarray) -> None:
        a = np.ascontiguousarray(array)
        if a.nbytes:
            cl.enqueue_copy(self.queue, buf, a)

    def fill(self, buf: cl.Buffer, value, nbytes: int) -> None:
        """Fill the first nbytes of buf with a 4-byte pattern (a float32, int32 or uint32 scalar)."""
        if nbytes:
            cl.enqueue_fill_buffer(self.queue, buf, value, 0, int(nbytes))
