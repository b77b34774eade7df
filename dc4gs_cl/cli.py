"""Command line: `dc4gs-cl devices | render | ...`.

Bad input (InputError) and device problems (DeviceError) end in one line on stderr and exit code 2;
anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from .errors import DeviceError, InputError
from .scene.builtin import BUILTIN_SCENE


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
    p.add_argument("--out", required=True, type=Path, help="output folder (PNGs under OUT/<split>/renders/)")
    p.add_argument("--split", choices=["test", "train", "all"], default="test")
    p.add_argument("-r", "--resolution", type=_resolution, default=None,
                   help="downscale images by this factor (default: widths above 1600 px scaled to 1600)")
    p.add_argument("--white-background", action="store_true", help="render onto white (Blender scenes)")
    p.add_argument("--profile", action="store_true", help="print per-stage device times (median over views)")
    _add_device(p)
    return parser


def cmd_devices(args) -> int:
    from .runtime import choose_device, describe, list_devices
    chosen, _ = choose_device(args.device)
    for key, dev in list_devices():
        print(f"{'*' if key == chosen else ' '} {key}  {describe(dev)}")
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
    cams = {"test": scene.test, "train": scene.train, "all": scene.train + scene.test}[args.split]
    if not cams:
        raise InputError(args.scene, f"the scene has no {args.split} cameras")
    rt = Runtime(args.device, profiling=args.profile)
    print(f"device: {describe(rt.device)}; {len(model):,} Gaussians (SH degree {model.sh_degree}); "
          f"{len(cams)} {args.split} views", file=sys.stderr)
    renderer = Renderer(rt)
    gaussians = DeviceGaussians(rt, model)
    final_dir = args.out / args.split / "renders"
    args.out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".render-", dir=args.out))
    timings = []
    try:
        for cam in cams:
            res = renderer.render(gaussians, cam, background=scene.background)
            write_png(staging / (Path(cam.name).stem + ".png"), res.image(rt))
            if args.profile:
                timings.append(rt.stage_times())
        final_dir.mkdir(parents=True, exist_ok=True)
        for f in sorted(staging.iterdir()):
            os.replace(f, final_dir / f.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    print(f"wrote {len(cams)} images to {final_dir}", file=sys.stderr)
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


COMMANDS = {"devices": cmd_devices, "render": cmd_render}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
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
