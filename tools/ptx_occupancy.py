"""Registers, stack and local memory of the rasterizer backward's GPU shape as NVIDIA's assembler allocates them,
and the work-groups an H100 / H200 multiprocessor then holds: the occupancy, without a GPU.

    python tools/ptx_occupancy.py [--layouts 3dgs absgs dc4gs] [--twin] [--arch sm_86]

Each variant's source (kernel_source, with the -D options the trainer builds it with on an NVIDIA GPU: one pixel
per work-item, batch 256, NVIDIA's inline-PTX subgroups) goes through clang's OpenCL front end with libclc's
NVPTX library (Debian: clang-14, libclc-14), LLVM's NVPTX back end (llc) and CUDA's ptxas -v. NVIDIA's OpenCL
compiler has its own front end, so its counts can differ: read these as before / after comparisons (on a GPU,
NVIDIA's -cl-nv-verbose prints its own). Work-groups per multiprocessor: 65,536 registers (allocated in 8s per
item), 2,048 items, 227 KB of local memory (1 KB of it reserved per group).
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from dc4gs_cl.backward.rasterize_backward import RasterizeBackward
from dc4gs_cl.render import StageContext
from dc4gs_cl.render.tuning import Tuning
from dc4gs_cl.runtime import Capabilities, Runtime, kernel_source
from dc4gs_cl.statistics import SumsLayout

LAYOUTS = {"3dgs": SumsLayout(), "absgs": SumsLayout(stats=True),
           "dc4gs": SumsLayout(stats=True, dc_stats=True, split_candidates=5)}
TOOLS = ("clang-14", "llvm-link-14", "opt-14", "llc-14", "ptxas")
LIBCLC = Path("/usr/lib/clc/nvptx64--nvidiacl.bc")
# NVIDIA H100 / H200 (compute capability 9.0) per multiprocessor
REGISTERS, ITEMS, LOCAL_BYTES, LOCAL_RESERVED = 65_536, 2_048, 227 * 1024, 1024
NVIDIA_GPU = Capabilities(is_cpu=False, compute_units=132, max_work_group_size=1024, local_mem_size=48 * 1024,
                          float_atomic_add=False, fp64=True, platform="NVIDIA CUDA", subgroups="ptx")


def groups_per_multiprocessor(registers: int, local_bytes: int, items: int) -> int:
    by_registers = REGISTERS // (-(-registers // 8) * 8 * items)
    return min(ITEMS // items, by_registers, LOCAL_BYTES // (local_bytes + LOCAL_RESERVED))


def assemble(source: str, options: list[str], arch: str, work: Path) -> dict[str, int]:
    """ptxas' registers, stack bytes and local (shared) bytes of the kernel."""
    (work / "k.cl").write_text(source)
    steps = [
        ["clang-14", "-x", "cl", "-cl-std=CL1.2", "-target", "nvptx64--nvidiacl", "-Xclang",
         "-fdeclare-opencl-builtins", "-include", "clc/clc.h", "-Dcl_clang_storage_class_specifiers",
         "-Dasm=__asm__", "-O3", "-emit-llvm", "-c", *options, "k.cl", "-o", "k.bc"],
        ["llvm-link-14", "k.bc", str(LIBCLC), "-o", "linked.bc"],
        ["opt-14", "-O3", "linked.bc", "-o", "opt.bc"],
        ["llc-14", f"-mcpu={arch}", "opt.bc", "-o", "k.ptx"],
        ["ptxas", f"-arch={arch}", "-v", "k.ptx", "-o", "k.cubin"],
    ]
    for step in steps:
        done = subprocess.run(step, cwd=work, capture_output=True, text=True)
        if done.returncode:
            raise RuntimeError(f"{step[0]} failed:\n{done.stderr[-3000:]}")
    info = done.stderr
    value = lambda pattern: int(m.group(1)) if (m := re.search(pattern, info)) else 0
    return {"registers": value(r"Used (\d+) registers"), "stack": value(r"(\d+) bytes cumulative stack"),
            "local": value(r"(\d+) bytes smem")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", nargs="+", choices=LAYOUTS, default=list(LAYOUTS))
    ap.add_argument("--twin", action="store_true", help="also the portable twin (32 pixels per item)")
    ap.add_argument("--arch", default="sm_86", help="the NVPTX target (clang 14 knows up to sm_86; the register "
                    "allocation of sm_90 is the same in these terms)")
    args = ap.parse_args(argv)
    missing = [tool for tool in TOOLS if shutil.which(tool) is None] + ([] if LIBCLC.exists() else [str(LIBCLC)])
    if missing:
        print(f"needs {', '.join(missing)} (Debian: clang-14 libclc-14 llvm-14; CUDA's ptxas)", file=sys.stderr)
        return 2
    rt = Runtime()   # any device: it only builds the -D options
    print("| layout | path | sum width | registers | stack bytes | local bytes | work-groups per multiprocessor |")
    print("|---|---|---|---|---|---|---|")
    for name in args.layouts:
        for subgroups in ("ptx", None) if args.twin else ("ptx",):
            tuning = Tuning.for_device(NVIDIA_GPU)
            backward = RasterizeBackward(StageContext(rt, Tuning(**{**tuning.__dict__, "subgroups": subgroups})))
            variant = {**LAYOUTS[name].defines(), "PIXEL_MASK": 0}
            shape = backward.shape(variant)
            defines = {**backward.defines(), **variant, **shape, "BATCH": tuning.batch}
            defines.update(backward.with_batch(defines, tuning.batch))
            options = [o for o in rt.build_options(defines) if o.startswith("-D")]
            with tempfile.TemporaryDirectory() as work:
                got = assemble(kernel_source("rasterize_backward.cl"), options, args.arch, Path(work))
            groups = groups_per_multiprocessor(got["registers"], got["local"], backward.items(shape))
            print(f"| {name} | {'subgroups (PTX)' if subgroups else 'twin'} | {defines['SUM_WIDTH']} | "
                  f"{got['registers']} | {got['stack']} | {got['local']:,} | {groups} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
