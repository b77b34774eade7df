"""OpenCL runtime: device choice, context and queue, the program registry, per-stage profiling.

One `Runtime` per process and device. Programs are built once per (kernel file, -D options) (PoCL and pyopencl
also keep compiled binaries on disk, so a new process builds fast); the stage hosts keep their `Kernel`
objects (render/stage.py), so nothing is rebuilt or looked up on the hot path, and `launch` sets only the
arguments that changed since a kernel's last launch (a quarter of them per training iteration). `#include
"x.h"` lines in kernel files are resolved here, textually (generated headers included), so the source text
alone decides what the driver caches. Every device buffer is made here (`buffer`, `to_device`), which counts
the bytes held (`memory_in_use`) and their high-water mark (`memory_peak`, restarted by
`reset_memory_peak()`).
"""
from __future__ import annotations

import math
import os
import re
import sys
import weakref
from collections import defaultdict
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyopencl as cl

from .constants import kernel_defines
from .errors import DeviceError
from .records import records_header

DEVICE_ENV = "DC4GS_DEVICE"   # same forms as --device: "P:D", "gpu", "cpu" or part of the name
RELAXED_MATH = "RELAXED_MATH"  # a define that, set to 1, also builds the program with -cl-fast-relaxed-math
BUFFER_HEADROOM = 0.125       # a buffer that must grow gets this much more than it needs: fewer reallocations
BUFFER_GROWTH = 1.5           # but at most this much more than it had

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
    """What a buffer (or array capacity) that holds `have` and must hold `want` grows to: `want` and
    BUFFER_HEADROOM of it more, so that a growing model or a busier view reallocates only after growing by that
    much, but never more than BUFFER_GROWTH x what it had, so that a jump (a model loaded into a trainer, a
    first frame) is met exactly. Headroom counts in the peak memory (the per-pair slots of DC4GS' backward are
    160 bytes a pair). The one growth rule."""
    return want if want <= have else min(int(want * (1 + BUFFER_HEADROOM)), max(want, int(have * BUFFER_GROWTH)))


ICD_VENDORS_ENV = "OCL_ICD_VENDORS"   # the ICD loader's folder of .icd files (default /etc/OpenCL/vendors)
SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
# Runtimes installed from PyPI whose bundled .icd names a placeholder path (the `intel` extra: intel-opencl-rt),
# by the library the loader must be given instead.
BUNDLED_RUNTIMES = ("libintelocl.so",)


def register_bundled_runtimes(prefix: Path = Path(sys.prefix), cache: Path | None = None) -> Path | None:
    """Let the ICD loader find the OpenCL runtimes installed in this environment whose own .icd is unusable:
    a vendors folder (in the user's cache) naming each by its absolute path beside links to the system's
    .icd files, set as OCL_ICD_VENDORS (which replaces the system folder). Nothing when the user set
    OCL_ICD_VENDORS or no such runtime is installed; returns the folder set, if any. Must run before the
    first platform query (list_devices calls it)."""
    libraries = [prefix / "lib" / name for name in BUNDLED_RUNTIMES if (prefix / "lib" / name).is_file()]
    if ICD_VENDORS_ENV in os.environ or not libraries:
        return None
    folder = (cache or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))) / "dc4gs-cl" / "icd-vendors"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for old in folder.glob("*.icd"):
            old.unlink()
        for lib in libraries:
            (folder / f"{lib.stem}.icd").write_text(f"{lib.resolve()}\n")
        for icd in sorted(SYSTEM_VENDORS.glob("*.icd")) if SYSTEM_VENDORS.is_dir() else []:
            (folder / f"system-{icd.name}").symlink_to(icd.resolve())
    except OSError:   # a read-only home: the bundled runtime stays unseen, as without this
        return None
    os.environ[ICD_VENDORS_ENV] = str(folder)
    return folder


def list_devices() -> list[tuple[str, cl.Device]]:
    """Every OpenCL device as ("P:D", device). Raises DeviceError when no platform exists."""
    register_bundled_runtimes()
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


# Platforms that simulate a device (to check kernels, hundreds of times slower): never chosen by default.
SIMULATORS = ("oclgrind",)
# CPU implementations in the order the default prefers them, each with why (measured on 2 AMD EPYC cores: the
# built-in scene's and the garden's frames, issue #11; `dc4gs-cl devices` shows the reason).
CPU_PREFERENCE = (
    ("intel(r) opencl", "Intel's CPU runtime: frames 11-24% faster than PoCL's, 3DGS iterations 6-23% "
                        "(`dc4gs-cl bench`; DC4GS iterations within 9% either way)"),
    ("portable computing language", "PoCL"),
)


def is_simulator(device: cl.Device) -> bool:
    return any(name in device.platform.name.lower() for name in SIMULATORS)


def default_device(devices: list[tuple[str, cl.Device]]) -> tuple[str, cl.Device, str]:
    """The device used when none is named, and why: the first GPU, else the preferred CPU implementation
    (CPU_PREFERENCE), else the first device; a simulator only when nothing else exists."""
    real = [(k, d) for k, d in devices if not is_simulator(d)]
    if not real:
        return *devices[0], "only a simulator is installed"
    gpus = [(k, d) for k, d in real if d.type & cl.device_type.GPU]
    if gpus:
        return *gpus[0], "the first GPU"
    cpus = [(k, d) for k, d in real if d.type & cl.device_type.CPU]
    for platform, why in CPU_PREFERENCE:
        for key, d in cpus:
            if platform in d.platform.name.lower():
                return key, d, why if len(cpus) > 1 else "the only CPU device"
    if cpus:
        return *cpus[0], "the first CPU device"
    return *real[0], "the first device"


def choose_device(spec: str | None = None) -> tuple[str, cl.Device]:
    """The device named by `spec` (or $DC4GS_DEVICE): "P:D" indices, "gpu", "cpu", or a case-insensitive
    part of "platform | device". With neither, default_device's (never a simulator unless named)."""
    devices = list_devices()
    spec = spec if spec is not None else os.environ.get(DEVICE_ENV) or None
    if spec is None:
        key, device, _ = default_device(devices)
        return key, device
    s = spec.strip().lower()
    for key, d in devices:
        if s == key:
            return key, d
    kinds = {"gpu": cl.device_type.GPU, "cpu": cl.device_type.CPU, "accelerator": cl.device_type.ACCELERATOR}
    matches = [(key, d) for key, d in devices
               if (s in kinds and d.type & kinds[s]) or (s not in kinds and s in describe(d).lower())]
    if matches:   # "gpu" / "cpu" never pick a simulator (Oclgrind calls itself every type) while another matches
        return next(((k, d) for k, d in matches if not is_simulator(d)), matches[0])
    names = "; ".join(f"{k} {describe(d)}" for k, d in devices)
    raise DeviceError(f"no OpenCL device matches '{spec}' (devices: {names})")


# Drivers that end every loop of a work-item early once it has run this many loop iterations in all (over all
# its loops), leaving results silently wrong: Mesa's llvmpipe (rusticl) before 25.0 keeps a loop limiter meant
# for graphics shaders (gallivm's LP_MAX_TGSI_LOOP_ITERATIONS, removed in Mesa 25.0.0, "gallivm: Remove loop
# limiting"). By (part of the platform name, first driver version without it, the limit).
LOOP_LIMITED_DRIVERS = (("rusticl", (25, 0), 65_535),)


def loop_limit(device: cl.Device) -> int | None:
    """The loop iterations one work-item may run in all on this device's driver (LOOP_LIMITED_DRIVERS);
    None where there is no such limit."""
    platform = device.platform.name.lower()
    version = tuple(int(v) for v in re.findall(r"\d+", device.driver_version)[:2])
    return next((limit for name, fixed, limit in LOOP_LIMITED_DRIVERS if name in platform and version < fixed), None)


@dataclass(frozen=True)
class Capabilities:
    is_cpu: bool
    compute_units: int
    max_work_group_size: int
    local_mem_size: int
    float_atomic_add: bool     # native float atomics (cl_ext_float_atomics); our kernels need none (see
                               # kernels/common.h), this is reported by `dc4gs-cl devices`
    fp64: bool
    loop_limit: int | None = None   # a driver defect: see LOOP_LIMITED_DRIVERS
    platform: str = ""              # the OpenCL platform's name: some shapes suit one implementation's compiler
    subgroups: str | None = None    # how 32 work-items exchange values (SUBGROUP_SOURCES), None: they cannot

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
            loop_limit=loop_limit(device),
            platform=device.platform.name,
            subgroups=subgroup_source(device),
        )

    def summary(self) -> str:
        return (f"work-groups up to {self.max_work_group_size}, {self.local_mem_size // 1024} KiB local memory, "
                f"float atomics: {'native' if self.float_atomic_add else 'none (compare-and-swap emulation)'}, "
                f"fp64: {'yes' if self.fp64 else 'no'}, "
                f"subgroups: {self.subgroups or 'none (the backward takes its portable twin)'}"
                + (f", loops cut after {self.loop_limit:,} iterations per work-item (a driver defect, gone in "
                   f"Mesa 25.0: renders take short-loop shapes; training is refused, its backward would be wrong)"
                   if self.loop_limit else ""))


# How 32 work-items exchange values (kernels/rasterize_backward.cl, -D SUBGROUP_SOURCE): NVIDIA's OpenCL has no
# subgroup functions but takes inline PTX (shfl.sync, vote.sync); elsewhere cl_khr_subgroup_shuffle (OpenCL C 2.0
# or later), in subgroups of a multiple of 32 (Intel's required size where it has one, AMD's 32 or 64: the backward
# checks the size it is given).
SUBGROUP_SOURCES = {"khr": 1, "ptx": 2}


def subgroup_source(device: cl.Device) -> str | None:
    if "nvidia" in device.platform.name.lower():
        return "ptx"
    version = tuple(int(v) for v in re.findall(r"\d+", device.opencl_c_version)[:2])
    return "khr" if "cl_khr_subgroup_shuffle" in device.extensions.split() and version >= (2, 0) else None


class KernelLimits(NamedTuple):
    work_group: int    # work-items per group
    local_bytes: int   # local memory the built kernel takes (its __local arrays)


class _Buffer(cl.Buffer):
    """A cl.Buffer that can be weakly referenced (pyopencl's cannot), so that its release can be counted."""


def _held_argument(value):
    """What Runtime keeps of a kernel argument it set, to tell whether the next launch passes the same: a scalar
    or record's bytes (the kernel receives nothing else), a buffer of ours as a weak reference (the same while
    that very object lives: a released buffer's handle may come back for another), else None (set every time)."""
    if isinstance(value, np.generic):
        return value.tobytes()
    return weakref.ref(value) if isinstance(value, _Buffer) else None


def _holds(held, value) -> bool:
    """Whether an argument kept by _held_argument is `value`."""
    if isinstance(value, np.generic):
        return held == value.tobytes()
    return isinstance(held, weakref.ref) and held() is value


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
        self._kernel_limits: dict[cl.Kernel, KernelLimits] = {}   # as the driver reports them
        self._kernel_arguments: dict[cl.Kernel, list] = {}         # as launch() last set them (_held_argument)
        self.events: dict[str, list[cl.Event]] = defaultdict(list)
        self.memory_in_use = 0   # bytes in device buffers made here and not yet released
        self.memory_peak = 0     # the most memory_in_use has been since the last reset_memory_peak()
        # Since the runtime was made: kernels enqueued, and the host's blocking waits on the queue (a read back,
        # or a write that waits for the queue before its copy); stage_times' own wait is the caller's, uncounted;
        # and the kernel arguments set (launch sets only those that changed).
        self.launches = 0
        self.syncs = 0
        self.arguments_set = 0

    def __repr__(self) -> str:
        return f"Runtime({self.device_key} {describe(self.device)})"

    # programs -----------------------------------------------------------------------------------
    def build_options(self, defines: dict | None = None, language: str = "CL1.2") -> list[str]:
        """-D options and flags; language: the OpenCL C version (CL1.2 but where a kernel needs subgroups)."""
        merged = {k: _format_define(v) for k, v in {**kernel_defines(), **(defines or {})}.items()}
        flags = ["-cl-fast-relaxed-math"] if merged.get(RELAXED_MATH) == "1" else []
        return [f"-D{k}={v}" for k, v in sorted(merged.items())] + [f"-cl-std={language}"] + flags

    def program(self, file: str, defines: dict | None = None, language: str = "CL1.2") -> cl.Program:
        key = (file, tuple(sorted((defines or {}).items())), language)
        prg = self._programs.get(key)
        if prg is None:
            options = self.build_options(defines, language)
            try:
                prg = cl.Program(self.context, kernel_source(file)).build(options=options)
            except cl.RuntimeError as e:
                raise DeviceError(f"building kernels/{file} with {' '.join(options)} failed:\n{e}") from None
            self._programs[key] = prg
        return prg

    # launches and buffers -----------------------------------------------------------------------
    def kernel_limits(self, kernel: cl.Kernel) -> KernelLimits:
        """A built kernel's limits on this device as its driver reports them, asked once per kernel: the largest
        work-group within the device's (a kernel's can be below it: registers on a GPU), and its local bytes."""
        driver = self._kernel_limits.get(kernel)
        if driver is None:
            info = cl.kernel_work_group_info
            driver = self._kernel_limits[kernel] = KernelLimits(
                kernel.get_work_group_info(info.WORK_GROUP_SIZE, self.device),
                kernel.get_work_group_info(info.LOCAL_MEM_SIZE, self.device))
        return driver._replace(work_group=min(driver.work_group, self.caps.max_work_group_size))

    def launch(self, stage: str, kernel: cl.Kernel, global_size, local_size, *args) -> cl.Event:
        """Enqueue a kernel; with profiling on, its event is kept under `stage`. A work-group beyond the kernel's
        limits is a DeviceError naming them (the stages choose shapes within them; this says which did not).
        Only the arguments that differ from the kernel's last launch here are set: setting one costs the host
        about what the enqueue does, and from one iteration to the next most stay the same (buffers, counts).
        So a kernel launched here must never have its arguments set elsewhere."""
        if isinstance(global_size, int):
            global_size = (global_size,)
        if isinstance(local_size, int):
            local_size = (local_size,)
        if local_size is not None:
            self.check_launch(stage, kernel, local_size)
        self._set_arguments(kernel, args)
        ev = cl.enqueue_nd_range_kernel(self.queue, kernel, global_size, local_size)
        self.launches += 1
        if self.profiling:
            self.events[stage].append(ev)
        return ev

    def _set_arguments(self, kernel: cl.Kernel, args: tuple) -> None:
        held = self._kernel_arguments.get(kernel)
        if held is None:
            held = self._kernel_arguments[kernel] = [None] * kernel.num_args
        if len(args) != len(held):
            raise DeviceError(f"kernel {kernel.function_name} takes {len(held)} arguments, given {len(args)}")
        for i, value in enumerate(args):
            if held[i] is None or not _holds(held[i], value):
                kernel.set_arg(i, value)
                held[i] = _held_argument(value)
                self.arguments_set += 1

    def check_launch(self, stage: str, kernel: cl.Kernel, local_size: tuple) -> None:
        items, (item_limit, local) = math.prod(local_size), self.kernel_limits(kernel)
        if items > item_limit or local > self.caps.local_mem_size:
            raise DeviceError(f"stage {stage}: kernel {kernel.function_name} launched in work-groups of {items} "
                              f"items taking {local:,} bytes of local memory; on {describe(self.device)} it "
                              f"allows {item_limit} items and {self.caps.local_mem_size:,} bytes")

    def launch_items(self, stage: str, kernel: cl.Kernel, n: int, wg: int, *args) -> cl.Event:
        """A 1D launch of n work-items (one per element) in work-groups of wg, or of the kernel's limit where
        that is less: the global size is n rounded up, so the kernel must bound-check its index against n."""
        wg = min(wg, self.kernel_limits(kernel).work_group)
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
            self.syncs += 1
        return out

    def to_host_later(self, buf: cl.Buffer, shape, dtype=np.float32) -> "HostRead":
        """Queue a copy of buf into a new host array without waiting: the host goes on queueing while the device
        runs up to the copy and past it; HostRead.result() waits for the copy alone (a blocking sync)."""
        out = np.empty(shape, dtype=dtype)
        event = cl.enqueue_copy(self.queue, out, buf, is_blocking=False) if out.nbytes else None
        return HostRead(self, out, event)

    def write(self, buf: cl.Buffer, array: np.ndarray) -> None:
        a = np.ascontiguousarray(array)
        if a.nbytes:
            cl.enqueue_copy(self.queue, buf, a)   # blocking: returns once the queue has run up to the copy
            self.syncs += 1

    def write_async(self, buf: cl.Buffer, array: np.ndarray) -> None:
        """Queue a copy of array into buf without waiting for it: array must stay as it is until the queue has run
        up to the copy (constants, images the scene keeps); pyopencl keeps it alive until then."""
        a = np.ascontiguousarray(array)
        if a.nbytes:
            cl.enqueue_copy(self.queue, buf, a, is_blocking=False)

    def fill(self, buf: cl.Buffer, value, nbytes: int) -> None:
        """Fill the first nbytes of buf with a 4-byte pattern (a float32, int32 or uint32 scalar)."""
        if nbytes:
            cl.enqueue_fill_buffer(self.queue, buf, value, 0, int(nbytes))


class HostRead:
    """A read queued by Runtime.to_host_later: result() waits for it once (flushing the queue first, so that the
    commands queued after the copy start meanwhile) and returns the host array."""

    def __init__(self, rt: Runtime, out: np.ndarray, event: cl.Event | None):
        self.rt, self.out, self.event = rt, out, event

    def result(self) -> np.ndarray:
        if self.event is not None:
            self.rt.queue.flush()
            self.event.wait()
            self.rt.syncs += 1
            self.event = None
        return self.out


class DeviceArrays:
    """Named (n, width) float32 arrays on the device sharing one Gaussian count and capacity: spare capacity
    (grown_size) so that densification does not reallocate every time. The parameters (render.gaussians), Adam's
    moments (optim) and the densification window (densify) are such arrays."""

    def __init__(self, rt: Runtime, widths: dict[str, int], n: int = 0):
        self.rt, self.widths = rt, dict(widths)
        self.n, self.capacity = 0, 0
        self.buffers: dict[str, cl.Buffer] = {}
        self.resize(n)

    def resize(self, n: int) -> None:
        """Set the count; growing past the capacity reallocates (contents are then undefined)."""
        if max(n, 1) > self.capacity:
            self.capacity = grown_size(max(n, 1), self.capacity)
            # Growing keeps no contents, so each old buffer goes before its larger one is made.
            for k, w in self.widths.items():
                self.buffers[k] = None
                self.buffers[k] = self.rt.buffer(4 * w * self.capacity)
        self.n = n

    @property
    def nbytes(self) -> int:
        """Device bytes held (capacity included)."""
        return sum(b.size for b in self.buffers.values())

    def upload(self, arrays: dict[str, np.ndarray]) -> None:
        """Replace the contents (and the count) with host arrays of shape (n, ...)."""
        n = len(next(iter(arrays.values())))
        self.resize(n)
        for name in self.widths:
            self.rt.write(self.buffers[name], np.ascontiguousarray(arrays[name], dtype=np.float32))

    def download(self) -> dict[str, np.ndarray]:
        return {k: self.download_group(k) for k in self.widths}

    def download_group(self, name: str) -> np.ndarray:
        return self.rt.to_host(self.buffers[name], (self.n, self.widths[name]))

    def upload_group(self, name: str, array: np.ndarray) -> None:
        self.rt.write(self.buffers[name],
                      np.ascontiguousarray(array, dtype=np.float32).reshape(self.n, self.widths[name]))

    def zero(self, name: str | None = None) -> None:
        """Zero every group (or only `name`) for the n Gaussians."""
        for k in ([name] if name else self.widths):
            self.rt.fill(self.buffers[k], np.float32(0), 4 * self.widths[k] * self.n)
