"""DC4GS overhead: what DC4GS adds to a training iteration over its base, measured on one trained state.

    python tools/bench_dc4gs.py [--scene builtin] [-r K] [--warm-iterations 1500] [--iterations 20]
                                [--rounds 5] [--base absgs] [--device D]

A base model is trained for --warm-iterations; then each configuration below steps --iterations times
from that same state (same Gaussians, same views, densification and opacity resets off, statistics on),
in --rounds interleaved rounds; per-stage device times (OpenCL profiling events) and wall times are
medians over the rounds, and every overhead is a ratio against the base measured in the same run.
Configurations: the base; +DCC; +DCS; +DC4GS (view pooling, the default) and with window pooling; with
split costs tracked only while the split criterion is at least 0.5 or 0.25 of the threshold
(--dcs-track, an approximation); split costs from every 2nd or 4th iteration's view only (--dcs-every, an
approximation); DCS splitting at the middle with no split costs (--split-pick middle, an
ablation that gains as much on the built-in scene: docs/dc4gs/studies.md); and two skips: split costs for every
visible Gaussian (instead of only those large enough to be split), and no statistics at all (what an
iteration costs once the densification window has closed). The trained state is reached without DC4GS,
so the tracking rows start a window with every Gaussian tracked, as every window does.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from dc4gs_cl.apps.bench import frozen_trainer
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.densify import DC4GSConfig
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.train import Trainer

CONFIGURATIONS = {   # name -> DC4GSConfig settings; "_" keys are the benchmark's own switches
    "base": {}, "+DCC": {"dcc": True}, "+DCS": {"dcs": True}, "+DC4GS": {"dcc": True, "dcs": True},
    "+DC4GS window": {"dcc": True, "dcs": True, "pooling": "window"},
    "+DC4GS, tracking 0.5": {"dcc": True, "dcs": True, "track": 0.5},
    "+DC4GS, tracking 0.25": {"dcc": True, "dcs": True, "track": 0.25},
    "+DC4GS, costs every 2nd view": {"dcc": True, "dcs": True, "cost_every": 2},
    "+DC4GS, costs every 4th view": {"dcc": True, "dcs": True, "cost_every": 4},
    "+DC4GS, middle split (no costs)": {"dcc": True, "dcs": True, "split_pick": "middle"},
    "+DC4GS, split costs for all": {"dcc": True, "dcs": True, "_all": True},
    "no statistics (window closed)": {"_closed": True},
}


def trainer_at(state, scene, rt, settings: dict, base: str, resolution) -> Trainer:
    """A trainer holding the given Gaussians (a GaussianSet), that gathers statistics but never densifies."""
    dc4gs = DC4GSConfig(**{k: v for k, v in settings.items() if not k.startswith("_")})
    cfg = TrainConfig(scene="bench", iterations=30_000, strategy=base, resolution=resolution, dc4gs=dc4gs)
    return frozen_trainer(cfg, scene, rt, state, 1_000, closed=settings.get("_closed", False),
                          split_costs_for_all=settings.get("_all", False))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="builtin")
    ap.add_argument("-r", "--resolution", type=int, default=None)
    ap.add_argument("--base", default="absgs", choices=("3dgs", "absgs", "pixelgs"))
    ap.add_argument("--warm-iterations", type=int, default=1500)
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)

    rt = Runtime(args.device, profiling=True)
    scene = load_scene(args.scene, resolution=args.resolution)
    warm = Trainer(TrainConfig(scene="bench", iterations=max(args.warm_iterations * 2, 2), strategy=args.base,
                               resolution=args.resolution), scene, rt)
    for _ in range(args.warm_iterations):
        warm.step()
    state = warm.model.download()
    cam = scene.train[0]
    print(f"device: {describe(rt.device)}\nscene {args.scene} {cam.width}x{cam.height}, {args.base} trained "
          f"{args.warm_iterations} iterations: {warm.params.n:,} Gaussians; {args.iterations} iterations x "
          f"{args.rounds} rounds per configuration")

    configs = CONFIGURATIONS
    trainers = {name: trainer_at(state, scene, rt, s, args.base, args.resolution) for name, s in configs.items()}
    times = {name: [] for name in configs}
    for name, trainer in trainers.items():       # warm-up: kernels built outside the timed rounds
        trainer.step()
        rt.stage_times()
    for _ in range(args.rounds):
        for name, trainer in trainers.items():
            for _ in range(args.iterations):
                trainer.step()
            times[name].append({k: v / args.iterations * 1e3 for k, v in rt.stage_times().items()})
    stages = list(dict.fromkeys(k for runs in times.values() for t in runs for k in t))
    medians = {name: {s: float(np.median([t.get(s, 0.0) for t in runs])) for s in stages}
               for name, runs in times.items()}
    base_total = sum(medians["base"].values())
    print("| configuration | device ms/it | vs base | " + " | ".join(stages) + " |")
    print("|---|---|---|" + "---|" * len(stages))
    for name, m in medians.items():
        total = sum(m.values())
        print(f"| {name} | {total:.2f} | {total / base_total - 1:+.1%} | "
              + " | ".join(f"{m[s]:.2f}" for s in stages) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
