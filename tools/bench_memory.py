"""Peak device memory per Gaussian while training, at model sizes where the Gaussians (not the images)
dominate.

    python tools/bench_memory.py [--gaussians 100000 400000] [--iterations 5] [--size 192x144] [--device D]

The built-in scene's trainer (its views rendered at --size) gets N random Gaussians (SH degree 3) in place
of its initial model and runs --iterations training steps with the densification statistics on (the most
memory an iteration uses), for the base strategy and with DC4GS (view and window pooling), and the base and DC4GS
again with --low-memory (float-atomic backward, no per-pair slots); the peak of the bytes held in device buffers
(Runtime.memory_peak) is divided by N. What is held per Gaussian is listed below the table.
"""
from __future__ import annotations

import argparse
import gc
import sys

import numpy as np

from dc4gs_cl.config import TrainConfig
from dc4gs_cl.densify import DC4GSConfig
from dc4gs_cl.model import GaussianSet
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.builtin import builtin_scene
from dc4gs_cl.reference.testing import random_model
from dc4gs_cl.train import Trainer

DC4GS = DC4GSConfig(dcc=True, dcs=True)
CONFIGS = {   # name -> TrainConfig settings; low_memory (--low-memory): the backward adds into per-Gaussian
             # sums with float atomics instead of per-pair slots (as fast, not bit-reproducible)
    "absgs": {}, "absgs+DC4GS": {"dc4gs": DC4GS},
    "absgs+DC4GS window": {"dc4gs": DC4GSConfig(dcc=True, dcs=True, pooling="window")},
    "absgs --low-memory": {"low_memory": True}, "absgs+DC4GS --low-memory": {"dc4gs": DC4GS, "low_memory": True}}


def trained_state(rt: Runtime, scene, n: int, iterations: int, settings: dict) -> tuple[Trainer, int]:
    """A trainer on N random Gaussians after a few steps, and the peak bytes it added."""
    gc.collect()
    rt.reset_memory_peak()
    before = rt.memory_in_use
    trainer = Trainer(TrainConfig(scene="bench", strategy="absgs", **settings), scene, rt)
    model = random_model(np.random.default_rng(0), n, sh_degree=3, spread=1.5, scale_range=(0.005, 0.03))
    params = model.groups()
    moments = lambda: {k: np.zeros_like(v) for k, v in params.items()}
    trainer.start_from(GaussianSet(params, moments(), moments()), 1_000)   # inside the window, between steps
    for _ in range(iterations):
        trainer.step()
    rt.queue.finish()
    return trainer, rt.memory_peak - before


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, nargs="+", default=[100_000, 400_000])
    ap.add_argument("--iterations", type=int, default=5)
    ap.add_argument("--size", default="192x144", help="the views' width x height in pixels (the per-pair buffers "
                    "grow with the frame: the backward's per-pair slots are held for runs of tiles on large frames)")
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    rt = Runtime(args.device)
    scene = builtin_scene(base_size=tuple(int(v) for v in args.size.split("x")))
    cam = scene.train[0]
    print(f"device: {describe(rt.device)}; built-in scene {cam.width}x{cam.height}, {args.iterations} iterations")
    print("| strategy | Gaussians | peak device MB | bytes per Gaussian |")
    print("|---|---|---|---|")
    details = {}
    for n in args.gaussians:
        for name, settings in CONFIGS.items():
            trainer, peak = trained_state(rt, scene, n, args.iterations, settings)
            print(f"| {name} | {n:,} | {peak / 2**20:.1f} | {peak / n:,.0f} |", flush=True)
            details[(name, n)] = trainer.memory_held()
            del trainer
    for (name, n), parts in details.items():
        if n == max(args.gaussians):
            print(f"\nheld after the steps, {name}, {n:,} Gaussians (bytes per Gaussian; capacity can exceed N):")
            for part, size in sorted(parts.items(), key=lambda kv: -kv[1]):
                if size / n >= 1:
                    print(f"  {part:28s} {size / n:8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
