"""`dc4gs-cl render`: a scene's cameras, or a camera path through them (video.py), rendered to PNG files from a
trained run, a model file or the Gaussians training would start from."""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np

from ..config import downscale_factor
from ..errors import InputError
from ..files import replace_folder, staging_folder
from ..run_folder import GROUND_TRUTH, RENDERS, RunFolder
from ..scene.builtin import BUILTIN_SCENE
from ..scene.paths import PATH_KINDS
from .model_source import ModelSource

DEFAULT_PATH_FRAMES, DEFAULT_FPS = 120, 30   # render --path: 4 seconds of video


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The `render` command's arguments (cli.py adds --antialiased, --check-finite and --device)."""
    source = p.add_mutually_exclusive_group()
    source.add_argument("--ply", type=Path, default=None, metavar="FILE",
                        help="a model file: a standard 3DGS PLY (SH degree 0..3) or any format `export` writes "
                             "(.splat, .spz, .compressed.ply); with neither --ply nor --model, the Gaussians "
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
    p.add_argument("-r", "--resolution", type=downscale_factor, default=None,
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


def cmd_render(args) -> int:
    from ..model import initial_model
    from ..render import DeviceGaussians, Renderer, RenderOptions
    from ..runtime import Runtime, describe
    from ..scene.loader import load_scene
    from ..scene.images import write_png

    if args.model is None and args.out is None:
        raise InputError(None, "render needs --out (or --model, a training output folder)")
    if args.iteration is not None and args.model is None:
        raise InputError(None, "--iteration needs --model")
    if args.model is not None:
        source = ModelSource.of_run(args.model, args.iteration)
        scene_name = args.scene or source.cfg.scene
        scene = source.run.load_scene(source.cfg, scene=args.scene, resolution=args.resolution,
                                      white_background=args.white_background)
    else:
        scene_name = args.scene or BUILTIN_SCENE
        scene = load_scene(scene_name, resolution=args.resolution, cache_dir=RunFolder(args.out).images_cache,
                           white_background=args.white_background)
        source = (ModelSource.of_file(args.ply) if args.ply else
                  ModelSource(initial_model(scene.points, scene.colors, np.random.default_rng(0))))
    if args.path is not None:
        return _render_path(args, source, scene)
    names = ["train", "test"] if args.split == "all" else [args.split]
    splits = {name: cams for name in names if (cams := getattr(scene, name))}
    if not splits:
        raise InputError(scene_name, f"the scene has no {args.split} cameras")
    cams = [c for split_cams in splits.values() for c in split_cams]
    model = source.model
    rt = Runtime(args.device, profiling=args.profile)
    print(f"device: {describe(rt.device)}; {len(model):,} Gaussians (SH degree {model.sh_degree}); "
          f"{len(cams)} {args.split} views", file=sys.stderr)
    renderer = Renderer(rt, options=RenderOptions.of_model(args.antialiased, source.antialiased),
                        check_finite=args.check_finite)
    gaussians = DeviceGaussians(rt, model)
    timings = []
    into_run = args.out is None   # renders beside their ground truth, as Inria's render.py
    for split, split_cams in splits.items():   # each split in its own folder: Blender scenes reuse names
        final_dir = source.run.views_dir(split, source.iteration) if into_run else args.out / split / RENDERS
        staging = staging_folder(final_dir)
        try:
            for cam in split_cams:
                renderer.context.check.at = f"view {cam.name}"
                res = renderer.render(gaussians, cam, background=scene.background)
                write_png(staging / (RENDERS if into_run else "") / f"{cam.file_stem}.png", res.image(rt))
                if into_run:
                    write_png(staging / GROUND_TRUTH / f"{cam.file_stem}.png", scene.image(cam))
                if args.profile:
                    timings.append(rt.stage_times())
            replace_folder(staging, final_dir)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        print(f"wrote {len(split_cams)} images to {final_dir}", file=sys.stderr)
    if args.profile:
        print_stage_table(timings, cams[0].width, cams[0].height)
    return 0


def _render_path(args, source: ModelSource, scene) -> int:
    """render --path: the frames of a camera path through the training cameras, and a video of them."""
    from ..render import DeviceGaussians, Renderer, RenderOptions
    from ..runtime import Runtime, describe
    from ..scene.paths import camera_path, cameras_behind, look_at_point
    from .video import render_path

    if args.fps < 1:
        raise InputError(None, f"--fps {args.fps} must be at least 1")
    cams = camera_path(scene.train, args.path, args.frames)
    if args.path == "orbit":   # cameras facing outwards, or away from each other, rendered black frames unsaid
        target = look_at_point(scene.train)
        behind = cameras_behind(scene.train, target)
        if 2 * behind > len(scene.train):
            print(f"warning: the training cameras look at no common point: the orbit's centre {np.round(target, 3)} "
                  f"lies behind {behind} of {len(scene.train)} of them, so its frames may show little; --path "
                  "interpolated follows the cameras instead", file=sys.stderr)
    if args.out is not None:
        frames_dir = RunFolder(args.out).path_frames_dir(args.path)
    else:
        frames_dir = source.run.path_frames_dir(args.path, source.iteration)
    model = source.model
    rt = Runtime(args.device)
    print(f"device: {describe(rt.device)}; {len(model):,} Gaussians (SH degree {model.sh_degree}); {args.path} path, "
          f"{len(cams)} frames of {cams[0].width}x{cams[0].height}", file=sys.stderr)
    renderer = Renderer(rt, options=RenderOptions.of_model(args.antialiased, source.antialiased),
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
