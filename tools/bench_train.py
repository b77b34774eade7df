"""Training benchmark: every COLMAP scene of ../shared/data trained with each densification strategy, one
markdown table row per (scene, strategy).

    python tools/bench_train.py [--scenes S ...] [--strategies 3dgs absgs pixelgs] [--iterations 3000] [-r K]
                                [--turn N] [--out DIR] [--json PATH] [--device D] [--quick] [--dc4gs]

A strategy is a base (3dgs, absgs, pixelgs) with optional DC4GS parts and settings: "absgs+dc4gs" (DCC and
DCS), "absgs+dcc", "absgs+dcs", and ":" options, e.g. "absgs+dc4gs:window:argmin" (pooling, split pick,
"abs" / "base" for the DCC reading, "track=F" for --dcs-track, "every=K" for --dcs-every, "shrink" for
--dcs-other-scale 0.625); "mcmc:cap=N" is MCMC with --max-gaussians N ("mcmc+dcs:cap=N" with DCS).
--dc4gs runs the DC4GS results table: each base with and without DC4GS and the AbsGS ablation (base, +DCC, +DCS,
+both), then prints each DC4GS row against its base.

A scene's runs train interleaved: each in turn trains --turn iterations (default 100) until all are done, so
that a slower or busier stretch of the machine falls on every run alike and the wall-time ratios between them
(printed against each DC4GS row's base) hold; --turn 0 trains them one after the other. Interleaving changes
no result, only when each iteration runs (tests/test_bench_train.py).

Per run, measured in this process through the library (each run its own Runtime, profiling on):
- test-view PSNR and SSIM (dc4gs_cl.evaluation.evaluate; every 8th image by name is a test view);
- Gaussians at the start, at the end and at their peak;
- wall time per iteration: Trainer.step() in a loop, from the first step until the queue is done after
  the last (densification included; evaluation, model saving and image decoding not);
- device time per iteration and stage, summed over the OpenCL profiling events of every training kernel;
- peak device memory: the high-water mark of the bytes held in device buffers (Runtime.memory_peak,
  restarted before each run once the previous run's buffers are gone), and that divided by the peak
  Gaussian count (it includes the per-image buffers, so it overstates what a Gaussian costs in small models);
- host peak RSS (getrusage), restarted before each run (interleaved: before each scene, so it is the peak
  of the scene's runs together) through /proc/self/clear_refs on Linux; where that is not possible it is the
  peak of the process so far (the JSON says which).

Images are read (and distorted ones undistorted) before a scene's first run, and each strategy's kernels
built by a two-step warm-up, so no run pays for either. The default -r makes every scene at most 400 px
wide (-r = ceil(width / 400)); the 3DGS schedule is scaled to --iterations by the trainer. Each run gets
its own output folder (DIR/<scene>-<strategy> with --out, else a temporary one) holding the final PLY,
results.json and the test renders, which `dc4gs-cl eval` can read.
"""
from __future__ import annotations

import argparse
import gc
import math
import resource
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from dc4gs_cl.config import TrainConfig
from dc4gs_cl.densify import STRATEGIES, DC4GSConfig
from dc4gs_cl.densify.ops import SPLIT_SCALE_DIVISOR
from dc4gs_cl.errors import InputError
from dc4gs_cl.evaluation.evaluate import evaluate
from dc4gs_cl.files import write_json
from dc4gs_cl.run_folder import RunFolder
from dc4gs_cl.runtime import Runtime, choose_device, describe
from dc4gs_cl.scene.camera import Scene
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.builtin import BUILTIN_SCENE
from dc4gs_cl.scene.colmap import model_dir
from dc4gs_cl.train import Trainer

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MAX_WIDTH = 400                # default -r: images at most this wide
QUICK_SCENES = ("temple_sparse_ring", "fountain_p11")
STAGES = ("project", "isect", "sort", "rasterize", "loss", "split_geometry", "rasterize_backward", "sum_pairs",
          "project_backward", "densify_stats")
TURN = 100                     # iterations each run trains before the next run's turn (interleaved)
EVENTS_EVERY = 100             # iterations between collections of the profiling events (bounds how many are held)
MB = 2 ** 20


def colmap_scenes() -> list[str]:
    return sorted(d.name for d in DATA.iterdir() if d.is_dir() and model_dir(d) is not None)


def reset_host_peak() -> bool:
    """Restart the peak RSS that getrusage reports (Linux); False where that is not possible."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def host_peak_bytes() -> int:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024   # bytes on macOS, kilobytes elsewhere


def scene_path(name: str) -> str | Path | None:
    """Where a --scenes entry is: "builtin", a COLMAP scene of DATA by its name, or a scene folder of the user's
    (COLMAP or NeRF) by its path; None where it is none of these."""
    if name == BUILTIN_SCENE:
        return BUILTIN_SCENE
    if (DATA / name).is_dir() and model_dir(DATA / name) is not None:
        return DATA / name
    return Path(name) if Path(name).is_dir() else None


def unknown_scenes(names: list[str]) -> str | None:
    """The error for --scenes entries that are no scene (None: all are), with what there is."""
    unknown = [s for s in names if scene_path(s) is None]
    available = ", ".join(colmap_scenes()) if DATA.is_dir() else "none"
    return (f"not COLMAP scenes of {DATA} nor scene folders: {', '.join(unknown)} (there are: {available})"
            if unknown else None)


def load(name: str, resolution: int | None, cache: Path, test_split: str = "llff") -> tuple[Scene, int]:
    """The scene (scene_path(name)) at -r `resolution` (default: at most MAX_WIDTH wide) with every image
    decoded."""
    path = scene_path(name)
    if resolution is None:
        full = load_scene(path, resolution=1)
        resolution = math.ceil(max(c.width for c in full.train + full.test) / MAX_WIDTH)
    scene = load_scene(path, resolution=resolution, cache_dir=cache / "undistorted" / Path(name).name,
                       test_split=test_split)
    scene.read_all_images()
    return scene, resolution


DC4GS_TABLE = ("3dgs", "3dgs+dc4gs", "absgs", "absgs+dcc", "absgs+dcs", "absgs+dc4gs", "pixelgs", "pixelgs+dc4gs")
PARTS = {"dc4gs": {"dcc": True, "dcs": True}, "dcc": {"dcc": True}, "dcs": {"dcs": True}}
OPTIONS = {"view": ("pooling", "view"), "window": ("pooling", "window"), "poly": ("split_pick", "poly"),
           "argmin": ("split_pick", "argmin"), "dense": ("split_pick", "dense"), "middle": ("split_pick", "middle"),
           "shrink": ("other_scale", 1 / SPLIT_SCALE_DIVISOR),
           "abs": ("dcc_reading", "abs"), "base": ("dcc_reading", "base")}
# "track=0.5": the DC4GSConfig field (or, for cap, the TrainConfig one: MCMC's --max-gaussians) and its type
VALUED = {"track": ("track", float), "every": ("cost_every", int), "cap": ("max_gaussians", int)}


def variant(spec: str) -> dict:
    """"absgs+dc4gs:window:track=0.5" -> {"strategy": base, **DC4GSConfig settings} (raises ValueError on
    anything unknown)."""
    head, *options = spec.split(":")
    base, *parts = head.split("+")
    valued = dict(o.split("=", 1) for o in options if "=" in o)
    options = [o for o in options if "=" not in o]
    if (base not in STRATEGIES or any(p not in PARTS for p in parts) or any(o not in OPTIONS for o in options)
            or any(k not in VALUED for k in valued)):
        raise ValueError(f"unknown strategy {spec!r}: a base ({', '.join(STRATEGIES)}), then +dc4gs, +dcc or "
                         f"+dcs, then :options ({', '.join(OPTIONS)}, or {', '.join(k + '=' for k in VALUED)})")
    settings = {"strategy": base}
    for p in parts:
        settings.update(PARTS[p])
    settings.update(dict(OPTIONS[o] for o in options))
    for key, value in valued.items():
        field, kind = VALUED[key]
        settings[field] = kind(value)
    return settings


def config(scene: Scene, strategy: str, iterations: int, resolution: int, **settings) -> TrainConfig:
    """The run's settings: the strategy spec's, then `settings` (TrainConfig fields, e.g. split_threshold)."""
    dc4gs = variant(strategy)
    if "max_gaussians" in dc4gs:
        settings = {"max_gaussians": dc4gs.pop("max_gaussians"), **settings}
    return TrainConfig(scene=str(scene.root), iterations=iterations, resolution=resolution,
                       strategy=dc4gs.pop("strategy"), dc4gs=DC4GSConfig(**dc4gs), **settings)


def dc4gs_summary(runs: list[dict]) -> list[str]:
    """Each DC4GS row against its base on the same scene: Gaussians and PSNR, and the paper's claim."""
    lines = ["| scene | variant | Gaussians vs base | PSNR vs base | SSIM vs base | wall time vs base |",
             "|---|---|---|---|---|---|"]
    by_key = {(r["scene"], r["strategy"]): r for r in runs}
    fewer, gain = {}, {}   # per variant ("+dc4gs", "+dcc", "+dc4gs:window", ...): over scenes and bases
    for r in runs:
        base_name = variant(r["strategy"])["strategy"]
        base = by_key.get((r["scene"], base_name))
        if base is None or base is r:
            continue
        dg = r["gaussians_final"] / base["gaussians_final"] - 1
        dp = r["psnr"] - base["psnr"]
        lines.append(f"| {r['scene']} | {r['strategy']} | {dg:+.1%} | {dp:+.2f} dB | {r['ssim'] - base['ssim']:+.4f} | "
                     f"{r['wall_ms_per_it'] / base['wall_ms_per_it'] - 1:+.1%} |")
        key = r["strategy"][len(base_name):]
        fewer.setdefault(key, []).append(-dg)
        gain.setdefault(key, []).append(dp)
    lines.append("")
    for key in fewer:
        n = len(fewer[key])
        lines.append(f"{key} over {n} (scene, base) pairs: {sum(fewer[key]) / n:.1%} fewer Gaussians on average, "
                     f"PSNR {sum(gain[key]) / n:+.2f} dB on average")
    lines.append("(paper, for +dc4gs: 17-24% fewer Gaussians at equal or better PSNR)")
    return lines


def warm_up(rt: Runtime, scene: Scene, strategies: list[str], resolution: int, out: Path) -> None:
    """Two iterations per strategy, so that its kernels are built on `rt` before anything is timed."""
    for strategy in strategies:
        trainer = Trainer(config(scene, strategy, 1000, resolution), scene, rt, out)
        for _ in range(2):
            trainer.step()
    rt.stage_times()


class BenchRun:
    """One training run in `out` on its own Runtime, trained in turns (advance) and then evaluated (finish): the
    measurements listed at the top."""

    def __init__(self, rt: Runtime, scene: Scene, cfg: TrainConfig, out: Path, reset_rss: bool):
        gc.collect()                           # released buffers go before the peaks restart
        self.rt, self.scene, self.cfg = rt, scene, cfg
        self.at_start = rt.memory_in_use
        rt.reset_memory_peak()
        self.rss_per_run = reset_host_peak() if reset_rss else False
        self.run = RunFolder(out)
        self.trainer = Trainer(cfg, scene, rt, self.run)
        self.run.write_settings(cfg, scene)
        self.initial = self.peak = self.trainer.params.n
        self.stages = Counter()
        self.wall = 0.0
        rt.stage_times()

    @property
    def done(self) -> bool:
        return self.trainer.iteration >= self.cfg.iterations

    def advance(self, iterations: int) -> None:
        """Train up to `iterations` more (all that are left for 0); the wall clock runs until the queue is done."""
        trainer, last = self.trainer, self.cfg.iterations
        stop = last if iterations <= 0 else min(last, trainer.iteration + iterations)
        start = time.perf_counter()
        while trainer.iteration < stop:
            trainer.step()
            self.peak = max(self.peak, trainer.params.n)
            if trainer.iteration % EVENTS_EVERY == 0 or trainer.iteration == stop:
                self.stages.update(self.rt.stage_times())   # waits for the queue
        self.wall += time.perf_counter() - start

    def finish(self) -> dict:
        rt, trainer, cfg = self.rt, self.trainer, self.cfg
        device_peak, host_peak = rt.memory_peak, host_peak_bytes()
        trainer.save_model()
        result = evaluate(rt, trainer.renderer, trainer.params, self.scene, self.scene.test, trainer.sh_degree,
                          self.run.views_dir("test", cfg.iterations))
        self.run.write_results(cfg.iterations, result)
        per_it = 1e3 / cfg.iterations
        return {"psnr": result["mean"]["PSNR"], "ssim": result["mean"]["SSIM"], "test_views": result["views"],
                "per_view_psnr": result["per_view"]["PSNR"],
                "gaussians_initial": self.initial, "gaussians_final": trainer.params.n, "gaussians_peak": self.peak,
                "wall_ms_per_it": self.wall * per_it,
                "device_ms_per_it": {s: t * per_it for s, t in self.stages.items()},
                "device_peak_bytes": device_peak, "device_bytes_at_start": self.at_start,
                "bytes_per_gaussian": device_peak / self.peak, "host_peak_rss_bytes": host_peak,
                "host_peak_rss_per_run": self.rss_per_run, "output": str(self.run.path)}


def train_one(rt: Runtime, scene: Scene, cfg: TrainConfig, out: Path) -> dict:
    """One run from start to end on `rt`, then evaluated."""
    run = BenchRun(rt, scene, cfg, out, reset_rss=True)
    run.advance(0)
    return run.finish()


def train_scene(device: str | None, name: str, scene: Scene, strategies: list[str], iterations: int,
                resolution: int, root: Path, warm: Path, turn: int) -> list[dict]:
    """Train every strategy on the scene, `turn` iterations each in turn (0: one run after the other); the
    results in the order of `strategies`."""
    runtimes = [Runtime(device, profiling=True) for _ in strategies]
    for rt, strategy in zip(runtimes, strategies):
        warm_up(rt, scene, [strategy], resolution, warm)
    cfgs = [config(scene, strategy, iterations, resolution) for strategy in strategies]
    folders = [root / f"{Path(name).name}-{strategy}" for strategy in strategies]
    if turn <= 0:
        return [train_one(rt, scene, cfg, out) for rt, cfg, out in zip(runtimes, cfgs, folders)]
    rss_scene = reset_host_peak()
    runs = [BenchRun(rt, scene, cfg, out, reset_rss=False) for rt, cfg, out in zip(runtimes, cfgs, folders)]
    while not all(run.done for run in runs):
        for run in runs:
            run.advance(turn)
    return [{**run.finish(), "host_peak_rss_per_scene": rss_scene} for run in runs]


HEADER = ("| scene | strategy | size | PSNR | SSIM | G init | G final | G peak | wall ms/it | "
          + " | ".join(STAGES) + " | B/Gaussian | device MB | RSS MB |")


def table_row(r: dict) -> str:
    stage_ms = " | ".join(f"{r['device_ms_per_it'].get(s, 0.0):.2f}" for s in STAGES)
    return (f"| {r['scene']} | {r['strategy']} | {r['size']} | {r['psnr']:.2f} | {r['ssim']:.4f} | "
            f"{r['gaussians_initial']:,} | {r['gaussians_final']:,} | {r['gaussians_peak']:,} | "
            f"{r['wall_ms_per_it']:.1f} | {stage_ms} | {r['bytes_per_gaussian']:,.0f} | "
            f"{r['device_peak_bytes'] / MB:.1f} | {r['host_peak_rss_bytes'] / MB:.0f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=None,
                    help=f"scenes of ../shared/data by name (default: every COLMAP one), {BUILTIN_SCENE}, or "
                         "the paths of scene folders of your own (COLMAP or NeRF)")
    ap.add_argument("--strategies", nargs="+", default=None,
                    help="densification strategies, e.g. absgs absgs+dc4gs absgs+dcc:window "
                         "(default: 3dgs absgs pixelgs)")
    ap.add_argument("--dc4gs", action="store_true", help=f"the DC4GS results table: {' '.join(DC4GS_TABLE)}")
    ap.add_argument("--iterations", type=int, default=None, help="iterations per run (default 3000)")
    ap.add_argument("-r", "--resolution", type=int, default=None,
                    help=f"downscale factor for every scene (default: per scene, at most {MAX_WIDTH} px wide)")
    ap.add_argument("--turn", type=int, default=TURN,
                    help=f"iterations each of a scene's runs trains in its turn (default {TURN}; 0: one run after "
                         "the other)")
    ap.add_argument("--out", type=Path, default=None, help="keep each run's folder under DIR (default: temporary)")
    ap.add_argument("--json", type=Path, default=None,
                    help="also write the results here (rewritten after each scene)")
    ap.add_argument("--device", default=None)
    ap.add_argument("--quick", action="store_true",
                    help=f"smoke test: one scene ({' or '.join(QUICK_SCENES)}), strategy 3dgs, 200 iterations")
    args = ap.parse_args(argv)
    available = colmap_scenes() if DATA.is_dir() else []
    if args.quick:
        args.scenes = args.scenes or [next((s for s in QUICK_SCENES if s in available), BUILTIN_SCENE)]
        args.strategies = args.strategies or ["3dgs"]
        args.iterations = args.iterations or 200
    scenes = args.scenes or available
    if not scenes:
        print(f"no scene data at {DATA}: nothing to benchmark (the COLMAP scenes of ../shared/data are needed; "
              f"--scenes {BUILTIN_SCENE} trains the built-in scene)")
        return 0
    strategies = args.strategies or (list(DC4GS_TABLE) if args.dc4gs else ["3dgs", "absgs", "pixelgs"])
    for spec in strategies:
        try:
            variant(spec)
        except ValueError as e:
            ap.error(str(e))
    iterations = args.iterations or 3000
    if problem := unknown_scenes(scenes):
        ap.error(problem)

    device = describe(choose_device(args.device)[1])
    order = f"interleaved, {args.turn} iterations a turn" if args.turn > 0 else "one after the other"
    print(f"device: {device}; {iterations:,} iterations per run; a scene's runs {order}", file=sys.stderr)
    report = {"device": device, "iterations": iterations, "turn": max(args.turn, 0), "runs": []}
    with tempfile.TemporaryDirectory(prefix="bench_train-") as tmp:
        root = args.out or Path(tmp)
        print(HEADER + "\n|" + "---|" * (HEADER.count("|") - 1), flush=True)
        for name in scenes:
            try:
                scene, r = load(name, args.resolution, root)
            except InputError as e:
                print(f"{name}: skipped, the scene does not load: {e}", file=sys.stderr)
                continue
            cam = scene.train[0]
            size = f"{cam.width}x{cam.height}"
            print(f"{name}: -r {r} -> {size}, {len(scene.train)} train / {len(scene.test)} test views, "
                  f"{len(scene.points):,} SfM points", file=sys.stderr)
            runs = train_scene(args.device, name, scene, strategies, iterations, r, root, Path(tmp) / "warm-up",
                               args.turn)
            for strategy, run in zip(strategies, runs):
                row = {"scene": name, "strategy": strategy, "resolution": r, "size": size, **run}
                report["runs"].append(row)
                print(table_row(row), flush=True)
            if args.json:
                write_json(args.json, report)
    if any("+" in s for s in strategies):
        print("\n" + "\n".join(dc4gs_summary(report["runs"])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
