"""The batch-size study: a scene trained on the same number of views (epochs) with a batch of B views per step on
P processes (`mpirun -n P dc4gs-cl train --batch B --iterations N/B`) against one view per step, seed by seed; one
markdown table of test PSNR / SSIM, Gaussians, wall time and what the gradients' sums over the processes cost.

    python tools/batch_study.py [--scene S] [-r K] [--views 3000] [--runs 1x1 2x2 4x4] [--seeds 0 1]
                                [--strategy absgs] [--out DIR]

A run "BxP" is a batch of B views on P processes (P = 1: one process, no MPI). Runs go through the command line
(each its own process or mpirun), into DIR/<scene>-bB-pP-sSEED, kept; a run whose results.json exists is not run
again. Wall time is the command's, start-up and the final evaluation included, on whatever else the machine runs.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

from dc4gs_cl.run_folder import RunFolder

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SUMS_LINE = re.compile(r"gradients summed over \d+ processes: ([\d.]+) MB and ([\d.]+) ms an iteration")


def run(scene: str, resolution: int | None, batch: int, processes: int, iterations: int, seed: int, strategy: str,
        out: Path) -> dict:
    """One training run through the command line; its results (PSNR, SSIM, Gaussians, wall s, sums' MB and ms)."""
    folder = out / f"{Path(scene).name}-b{batch}-p{processes}-s{seed}"
    record = folder / "study.json"
    if record.is_file():
        return json.loads(record.read_text())
    train = [sys.executable, "-m", "dc4gs_cl", "train", "--scene", scene, "--batch", str(batch), "--iterations",
             str(iterations), "--seed", str(seed), "--strategy", strategy, "--out", str(folder), "--force",
             "--no-progress", "--lpips", "none", *(["-r", str(resolution)] if resolution else [])]
    if processes > 1:
        mpirun = shutil.which("mpirun", path=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
        train = [mpirun, "--allow-run-as-root", "--oversubscribe", "-n", str(processes), *train]
    start = time.perf_counter()
    proc = subprocess.run(train, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"{' '.join(train)} failed:\n{proc.stderr[-2000:]}")
    results = RunFolder(folder).read_results(iterations)
    gaussians = int(re.search(r"; ([\d,]+) Gaussians", proc.stdout).group(1).replace(",", ""))
    sums = SUMS_LINE.search(proc.stdout)
    entry = {"batch": batch, "processes": processes, "iterations": iterations, "seed": seed, "psnr": results["PSNR"],
             "ssim": results["SSIM"], "gaussians": gaussians, "wall_s": seconds,
             "sums_mb": float(sums.group(1)) if sums else None, "sums_ms": float(sums.group(2)) if sums else None}
    record.write_text(json.dumps(entry))
    return entry


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(DATA / "temple_sparse_ring"))
    ap.add_argument("-r", "--resolution", type=int, default=2)
    ap.add_argument("--views", type=int, default=3000, help="views seen by each run (iterations x batch)")
    ap.add_argument("--runs", nargs="+", default=["1x1", "2x2", "4x4"], help="BxP: batch B on P processes")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--strategy", default="absgs")
    ap.add_argument("--out", type=Path, default=Path("batch-study"))
    args = ap.parse_args(argv)
    specs = [tuple(map(int, r.split("x"))) for r in args.runs]
    if any(b % p or args.views % b for b, p in specs):
        ap.error("each batch must be a multiple of its processes and divide --views")
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [f"{Path(args.scene).name} (-r {args.resolution}), {args.strategy}, {args.views:,} views per run", "",
             "| batch x processes | iterations | seed | PSNR | SSIM | Gaussians | wall s | "
             "sums MB / it | sums ms / it |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for seed in args.seeds:
        for batch, processes in specs:
            e = run(args.scene, args.resolution, batch, processes, args.views // batch, seed, args.strategy, args.out)
            sums = (f"{e['sums_mb']:.2f} | {e['sums_ms']:.1f}" if e["sums_mb"] is not None else "- | -")
            lines.append(f"| {batch} x {processes} | {e['iterations']:,} | {seed} | {e['psnr']:.2f} | "
                         f"{e['ssim']:.4f} | {e['gaussians']:,} | {e['wall_s']:.0f} | {sums} |")
            print(lines[-1], flush=True)
    (args.out / "batch-study.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
