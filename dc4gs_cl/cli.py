"""Command line: `dc4gs-cl devices | render | ...`.

Bad input (InputError) and device problems (DeviceError) end in one line on stderr and exit code 2;
anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from .errors import DeviceError, InputError
from .files import replace_folder, staging_folder
from .host.strategy import STRATEGIES as STRATEGY_NAMES
from .scene.builtin import BUILTIN_SCENE
from .host.dc4gs import DCC_READINGS, DENSE_CANDIDATES, POOLINGS, SPLIT_PICKS
from .train import RECIPE_ITERATIONS

BUILTIN_ITERATIONS = 5_000   # the default run on the built-in scene: about five minutes on 2 CPU cores


def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default=None,
                   help='OpenCL device: "P:D" (see `dc4gs-cl devices`), "gpu", "cpu" or part of its name; '
                        "default $DC4GS_DEVICE, else the first GPU, else PoCL's CPU device")


def _resolution(value: str) -> int:
    r = int(value)
    if r < 1:
        raise argparse.ArgumentTypeError("-r must be a positive integer (1, 2, 4, 8, ...)")
    return r


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dc4gs-cl", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("devices", help="list OpenCL platforms and devices, and the one that would be chosen")
    _add_device(p)

    p = sub.add_parser("render", help="render a scene's cameras from a 3DGS PLY to PNG files")
    p.add_argument("--ply", type=Path, default=None,
                   help="a standard 3DGS PLY (SH degree 0..3); without it, the Gaussians training would start "
                        "from (the scene's SfM points), which shows whether a scene's cameras are read right")
    p.add_argument("--scene", default=BUILTIN_SCENE,
                   help=f'COLMAP or NeRF (transforms*.json) scene folder, or "{BUILTIN_SCENE}" (the default)')
    p.add_argument("--out", required=True, type=Path, help="output folder (PNGs under OUT/<split>/renders/; --split all writes train/ and test/)")
    p.add_argument("--split", choices=["test", "train", "all"], default="test")
    p.add_argument("-r", "--resolution", type=_resolution, default=None,
                   help="downscale images by this factor (default: widths above 1600 px scaled to 1600)")
    p.add_argument("--white-background", action="store_true", help="render onto white (Blender scenes)")
    p.add_argument("--profile", action="store_true", help="print per-stage device times (median over views)")
    _add_device(p)

    p = sub.add_parser("train", help="train a scene (no arguments: the built-in scene, three to five minutes on 2 cores)")
    p.add_argument("--scene", default=None,
                   help=f'COLMAP or NeRF scene folder, or "{BUILTIN_SCENE}" (the default)')
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default output/<scene>-<date-time>): point_cloud/iteration_N/point_cloud.ply, "
                        "cameras.json, config.json, checkpoint.npz, results.json, test/ renders")
    p.add_argument("--strategy", choices=sorted(STRATEGY_NAMES), default=None, help="densification criterion (3dgs)")
    p.add_argument("--iterations", type=int, default=None,
                   help=f"training iterations (default {RECIPE_ITERATIONS:,}; {BUILTIN_ITERATIONS:,} for the built-in "
                        f"scene). Runs shorter than {RECIPE_ITERATIONS:,} scale the 3DGS schedule to their length")
    p.add_argument("-r", "--resolution", type=_resolution, default=None,
                   help="downscale images by this factor (default: widths above 1600 px scaled to 1600)")
    p.add_argument("--test-every", type=int, default=None, help="every N-th image (by name) is a test image (8; 0: none)")
    p.add_argument("--save-at", type=int, nargs="*", default=None, help="also write the PLY at these iterations")
    p.add_argument("--densify-until", type=int, default=None, help="end of the densification window (0: no densification)")
    p.add_argument("--checkpoint-every", type=int, default=None, help="iterations between checkpoints (1000)")
    p.add_argument("--seed", type=int, default=None, help="random seed: the same seed gives the same model (0)")
    p.add_argument("--sh-degree", type=int, default=None, help="largest spherical-harmonics degree, 0 to 3 (3)")
    p.add_argument("--white-background", action="store_true", default=None, help="white background (Blender scenes)")
    g = p.add_argument_group("DC4GS (directional-consistency density control, on any base strategy)")
    g.add_argument("--dc4gs", action="store_true", default=None, help="DCC and DCS together")
    g.add_argument("--dcc", action="store_true", default=None,
                   help="DC-weighted split criterion: a Gaussian is split only where its pixels' gradients disagree")
    g.add_argument("--dcs", action="store_true", default=None,
                   help="DC-guided split: children placed on the principal axis where the costs say, not at random")
    g.add_argument("--dc-pooling", choices=POOLINGS, default=None,
                   help="directional consistency per view (view: the paper; default) or over the densification "
                        "window (window: the authors' release)")
    g.add_argument("--split-pick", choices=SPLIT_PICKS, default=None,
                   help="split position: minimum of the polynomial through the candidates' costs (poly, default), "
                        f"the best candidate (argmin), or the best of many candidates (dense: {DENSE_CANDIDATES})")
    g.add_argument("--split-candidates", type=int, default=None, help="candidate split positions (odd; default 5)")
    g.add_argument("--dcs-track", type=float, default=None,
                   help="gather split costs for a Gaussian only in its first views of a window and while its running "
                        "split criterion is at least this fraction of the threshold (0: every Gaussian that can be "
                        "split, exact; see the README)")
    g.add_argument("--dcc-reading", choices=DCC_READINGS, default=None,
                   help="what DCC weights on the 3DGS and Pixel-GS bases: the base's own term (base, the paper's "
                        "literal reading; default) or the homodirectional gradient (abs)")
    p.add_argument("--low-memory", action="store_true", default=None,
                   help="the backward adds into per-Gaussian sums with float atomics instead of per-pair slots: "
                        "about 17%% less device memory, as fast, not bit-reproducible from run to run")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--force", action="store_true", help="replace a previous run's files in --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--profile", action="store_true", help="print per-stage device time per iteration at the end")
    _add_device(p)

    p = sub.add_parser("eval", help="render a trained model's test views and write PSNR / SSIM (results.json)")
    p.add_argument("--model", type=Path, required=True, help="a training output folder")
    p.add_argument("--iteration", type=int, default=None, help="which saved iteration (default: the last)")
    p.add_argument("--no-renders", action="store_true", help="metrics only, no PNGs under test/")
    _add_device(p)
    return parser


def cmd_devices(args) -> int:
    from .runtime import Capabilities, choose_device, describe, list_devices
    chosen, _ = choose_device(args.device)
    for key, dev in list_devices():
        print(f"{'*' if key == chosen else ' '} {key}  {describe(dev)}")
        print(f"      {Capabilities.of(dev).summary()}")
    print("(* = the device dc4gs-cl would use; choose another with --device or $DC4GS_DEVICE)")
    return 0


def cmd_render(args) -> int:
    from .model import initial_model
    from .ply import read_ply
    from .render import DeviceGaussians, Renderer
    from .runtime import Runtime, describe
    from .scene import load_scene
    from .scene.images import write_png

    scene = load_scene(args.scene, resolution=args.resolution, cache_dir=args.out / "undistorted",
                       white_background=args.white_background)
    model = read_ply(args.ply) if args.ply else initial_model(scene.points, scene.colors, np.random.default_rng(0))
    names = ["train", "test"] if args.split == "all" else [args.split]
    splits = {name: cams for name in names if (cams := getattr(scene, name))}
    if not splits:
        raise InputError(args.scene, f"the scene has no {args.split} cameras")
    cams = [c for split_cams in splits.values() for c in split_cams]
    rt = Runtime(args.device, profiling=args.profile)
    print(f"device: {describe(rt.device)}; {len(model):,} Gaussians (SH degree {model.sh_degree}); "
          f"{len(cams)} {args.split} views", file=sys.stderr)
    renderer = Renderer(rt)
    gaussians = DeviceGaussians(rt, model)
    timings = []
    for split, split_cams in splits.items():   # each split in its own folder: Blender scenes reuse names
        final_dir = args.out / split / "renders"
        staging = staging_folder(final_dir)
        try:
            for cam in split_cams:
                res = renderer.render(gaussians, cam, background=scene.background)
                write_png(staging / f"{cam.file_stem}.png", res.image(rt))
                if args.profile:
                    timings.append(rt.stage_times())
            replace_folder(staging, final_dir)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        print(f"wrote {len(split_cams)} images to {final_dir}", file=sys.stderr)
    if args.profile:
        print_stage_table(timings, cams[0].width, cams[0].height)
    return 0


def print_stage_table(timings: list[dict[str, float]], width: int, height: int) -> None:
    stages = list(dict.fromkeys(s for t in timings for s in t))
    print(f"per-stage device time, median over {len(timings)} views ({width}x{height} px for the first view):")
    total = 0.0
    for s in stages:
        med = float(np.median([t.get(s, 0.0) for t in timings])) * 1e3
        total += med
        print(f"  {s:12s} {med:9.2f} ms")
    print(f"  {'total':12s} {total:9.2f} ms")


def train_config(args, out: Path):
    """The run's settings: from the arguments, or with --resume from the run's config.json (explicit
    arguments must then agree with it)."""
    from dataclasses import fields
    from .train import CONFIG, TrainConfig
    if args.dc4gs:
        args.dcc = args.dcs = True
    # the TrainConfig fields the command line sets (each flag defaults to None: "not given")
    given = {f.name: getattr(args, f.name) for f in fields(TrainConfig) if getattr(args, f.name, None) is not None}
    if "save_at" in given:
        given["save_at"] = tuple(given["save_at"])
    if "scene" in given and given["scene"] != BUILTIN_SCENE:
        given["scene"] = str(Path(given["scene"]).resolve())
    if args.resume:
        path = out / CONFIG
        if not path.is_file():
            raise InputError(out, "nothing to resume: no config.json from an earlier run")
        try:
            cfg = TrainConfig.from_json(json.loads(path.read_text()))
        except (ValueError, TypeError) as e:
            raise InputError(path, f"unreadable run settings ({e})") from None
        clash = {k: v for k, v in given.items() if getattr(cfg, k) != v}
        if clash:
            raise InputError(path, "--resume continues the saved settings; these differ: " +
                             ", ".join(f"{k} {getattr(cfg, k)!r} (saved) vs {v!r}" for k, v in clash.items()))
        return cfg
    given.setdefault("scene", BUILTIN_SCENE)
    given.setdefault("iterations", BUILTIN_ITERATIONS if given["scene"] == BUILTIN_SCENE else RECIPE_ITERATIONS)
    for flag in ("white_background", "dcc", "dcs"):
        given[flag] = bool(given.get(flag))
    return TrainConfig(**given)


def cmd_train(args) -> int:
    import time
    from .evaluate import evaluate, write_results
    from .runtime import Runtime, describe
    from .scene import load_scene
    from .train import CHECKPOINT, Trainer, clear_run, holds_run, write_run_files

    if args.out is None:
        if args.resume:
            raise InputError(None, "--resume needs --out (the folder of the run to continue)")
        name = Path(args.scene).resolve().name if args.scene and args.scene != BUILTIN_SCENE else BUILTIN_SCENE
        args.out = Path("output") / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
    out = args.out
    if args.resume and args.force:
        raise InputError(None, "--resume and --force exclude each other")
    if args.resume and not (out / CHECKPOINT).is_file():
        raise InputError(out, "nothing to resume: no checkpoint.npz")
    if not args.resume and holds_run(out) and not args.force:
        raise InputError(out, "holds another run: continue it with --resume, or replace it with --force")
    cfg = train_config(args, out)
    scene = load_scene(cfg.scene, resolution=cfg.resolution, cache_dir=out / "undistorted",
                       test_every=cfg.test_every, white_background=cfg.white_background)
    rt = Runtime(args.device, profiling=args.profile)
    trainer = Trainer(cfg, scene, rt, out)
    if args.resume:
        trainer.load_checkpoint(out / CHECKPOINT)
    else:
        if args.force:
            clear_run(out)
        write_run_files(out, cfg, scene)
    print(f"device: {describe(rt.device)}\nscene: {cfg.scene} ({len(scene.train)} train / {len(scene.test)} test views, "
          f"{scene.train[0].width}x{scene.train[0].height}), strategy {trainer.strategy.label}, {cfg.iterations:,} iterations, "
          f"{trainer.params.n:,} initial Gaussians\noutput: {out}", file=sys.stderr)
    start, first = time.perf_counter(), trainer.iteration
    try:
        trainer.run(progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"stopped at iteration {trainer.iteration}; a checkpoint is in {out}. Continue with: "
              f"dc4gs-cl train --out {out} --resume", file=sys.stderr)
        return 130
    seconds = time.perf_counter() - start
    if args.profile:
        times = rt.stage_times()
        done = max(trainer.iteration - first, 1)
        print("device time per iteration: " + ", ".join(f"{k} {v / done * 1e3:.2f} ms" for k, v in times.items()))
    print(f"trained {trainer.iteration - first:,} iterations in {seconds:.0f} s "
          f"({(trainer.iteration - first) / max(seconds, 1e-9):.1f} it/s); {trainer.params.n:,} Gaussians")
    if scene.test:
        result = evaluate(rt, trainer.renderer, trainer.params, scene, scene.test, trainer.sh_degree,
                          out / "test" / f"ours_{trainer.iteration}")
        write_results(out, trainer.iteration, result)
        print(f"test views: PSNR {result['mean']['PSNR']:.2f} dB, SSIM {result['mean']['SSIM']:.4f} "
              f"({result['views']} views; LPIPS skipped: {result['lpips']})")
    print(f"model: {out / 'point_cloud' / f'iteration_{trainer.iteration}' / 'point_cloud.ply'}")
    return 0


def cmd_eval(args) -> int:
    import re
    from .evaluate import evaluate, write_results
    from .ply import read_ply
    from .render import DeviceGaussians, Renderer
    from .runtime import Runtime
    from .scene import load_scene
    from .train import CONFIG, TrainConfig

    model_dir = args.model
    path = model_dir / CONFIG
    if not path.is_file():
        raise InputError(model_dir, "not a training output folder (no config.json)")
    try:
        cfg = TrainConfig.from_json(json.loads(path.read_text()))
    except (ValueError, TypeError) as e:
        raise InputError(path, f"unreadable run settings ({e})") from None
    saved = sorted(int(m.group(1)) for d in (model_dir / "point_cloud").glob("iteration_*")
                   if (m := re.fullmatch(r"iteration_(\d+)", d.name)) and (d / "point_cloud.ply").is_file())
    if not saved:
        raise InputError(model_dir / "point_cloud", "no saved model (point_cloud/iteration_N/point_cloud.ply)")
    iteration = args.iteration if args.iteration is not None else saved[-1]
    if iteration not in saved:
        raise InputError(model_dir / "point_cloud", f"no model saved at iteration {iteration} (saved: {saved})")
    model = read_ply(model_dir / "point_cloud" / f"iteration_{iteration}" / "point_cloud.ply")
    scene = load_scene(cfg.scene, resolution=cfg.resolution, cache_dir=model_dir / "undistorted",
                       test_every=cfg.test_every, white_background=cfg.white_background)
    if not scene.test:
        raise InputError(model_dir / CONFIG, "the run has no test views (test_every = 0)")
    rt = Runtime(args.device)
    result = evaluate(rt, Renderer(rt), DeviceGaussians(rt, model), scene, scene.test, model.sh_degree,
                      None if args.no_renders else model_dir / "test" / f"ours_{iteration}")
    write_results(model_dir, iteration, result)
    print(f"iteration {iteration}: PSNR {result['mean']['PSNR']:.2f} dB, SSIM {result['mean']['SSIM']:.4f} over "
          f"{result['views']} test views (LPIPS skipped: {result['lpips']}); written to {model_dir / 'results.json'}")
    return 0


COMMANDS = {"devices": cmd_devices, "render": cmd_render, "train": cmd_train, "eval": cmd_eval}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv if argv is not None else (sys.argv[1:] or ["train"]))
    try:
        return COMMANDS[args.command](args)
    except (InputError, DeviceError) as e:
        print(f"dc4gs-cl {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dc4gs-cl {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
