"""What summing the gradients over the processes of a parallel run costs per iteration, for a model of N Gaussians:
parallel.MPIGroup.sum_gradients (device to host, MPI Allreduce, host to device) on random gradients, median of
--rounds, under mpirun.

    mpirun -n 2 python tools/bench_allreduce.py [--gaussians 1000000 ...] [--rounds 10] [--device D]
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from dc4gs_cl.model import group_widths
from dc4gs_cl.train.parallel import device_of_process, process_group
from dc4gs_cl.runtime import DeviceArrays, Runtime, describe


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, nargs="+", default=[20_000, 100_000, 1_000_000])
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    group = process_group()
    if group.size < 2:
        ap.error("run it under mpirun with 2 or more processes")
    rt = Runtime(device_of_process(group, args.device))
    widths = group_widths(16)   # SH degree 3
    rng = np.random.default_rng(group.rank)
    lines = [f"{group.size} processes, {describe(rt.device)}", "",
             "| Gaussians | MB each process sends | ms (median) |", "|---:|---:|---:|"]
    for n in args.gaussians:
        sums = DeviceArrays(rt, widths, n)
        sums.upload({k: rng.normal(size=(n, w)).astype(np.float32) for k, w in widths.items()})
        times = []
        for _ in range(args.rounds):
            group.comm.Barrier()
            start = time.perf_counter()
            group.sum_gradients(sums)
            times.append(time.perf_counter() - start)
        lines.append(f"| {n:,} | {4 * sum(widths.values()) * n / 1e6:.1f} | {np.median(times) * 1e3:.1f} |")
    if group.writes:
        print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
