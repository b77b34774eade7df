"""`dc4gs-cl train`: its arguments (the flags config.TRAIN_FLAGS declares, then the command's own), the run's
settings from them (train_config), and the training run in its folder: one run per folder, resumed from its
checkpoint, under mpirun one process of several (train/parallel.py)."""
from __future__ import annotations

import argparse
import sys
import time
from contextlib import nullcontext
from pathlib import Path

from ..config import (BUILTIN_ITERATIONS, DEFAULT_LINE_EVERY, FLAG_OF, FLAGS, RECIPE_ITERATIONS, SETTINGS, TRAIN_FLAGS,
                      Flag, FlagGroup, TrainConfig, flag_key, setting_value)
from ..errors import InputError
from ..run_folder import CONFIG, CORRUPT_CHECKPOINT, RunFolder
from ..scene.builtin import BUILTIN_SCENE
from ..scene.camera import lens_models, view_sizes
from .sfm import add_settings as add_sfm_settings, scene_for_training
from .viewer import DEFAULT_PORT, Viewer


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The `train` command's arguments (cli.py adds --lpips, --check-finite and --device)."""
    for group in TRAIN_FLAGS:
        into = p if group.title is None else p.add_argument_group(group.title)
        for flag in group.flags:
            _add_flag(into, flag, group)
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
    add_sfm_settings(p.add_argument_group("structure from motion (a --scene folder of photos or a video, see "
                                          "`dc4gs-cl sfm`)"))


def _add_flag(into, flag: Flag, group: FlagGroup) -> None:
    """One of TRAIN_FLAGS as an argument, defaulting to None ("not given")."""
    names = ((flag.short,) if flag.short else ()) + (flag.name,)
    if group.inria_spellings:
        names += ("--" + flag_key(flag.name),)
    if flag.type is bool:
        into.add_argument(*names, action="store_true", default=None, help=flag.text)
    else:
        metavar = ("N" if flag.type is int else "X") if group.metavars else None
        into.add_argument(*names, type=flag.type, choices=flag.choices, nargs=flag.nargs, default=None,
                          metavar=metavar, help=flag.text)


def train_config(args, run: RunFolder | None, processes: int = 1) -> TrainConfig:
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
            raise InputError(run.path, f"nothing to resume: no {CONFIG} from an earlier run")
        cfg = run.read_config()
        clash = {k: (saved, v) for k, v in given.items() if (saved := setting_value(cfg, k)) != v}
        if clash:
            raise InputError(run.config_path, "--resume continues the saved settings; these differ: " +
                             ", ".join(f"{k} {a!r} (saved) vs {b!r}" for k, (a, b) in clash.items()))
        return cfg
    given.setdefault("scene", BUILTIN_SCENE)
    given.setdefault("batch", processes)
    given.setdefault("iterations", BUILTIN_ITERATIONS if given["scene"] == BUILTIN_SCENE else RECIPE_ITERATIONS)
    return TrainConfig.from_settings(given)


def cmd_train(args) -> int:
    from ..train.parallel import process_group

    group = process_group()   # under mpirun: the processes training together (train/parallel.py)
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


def _train_locked(args, run: RunFolder, group) -> int:
    """cmd_train in its run folder, which it holds (process 0 of a parallel run; the others follow it, writing
    nothing)."""
    from ..evaluation.evaluate import per_view_lines, summary
    from ..evaluation.metrics import lpips_metric
    from ..train.parallel import device_of_process
    from ..runtime import Runtime, describe
    from ..train import Stopped, Trainer
    from ..train.log import progress_mode

    # each refusal names the one flag that works: a run killed before its first checkpoint cannot be resumed
    missing = run.missing_for_resume()
    if args.resume and missing:
        raise InputError(run.path, f"nothing to resume: no {missing}; " + (
            "replace what it holds with --force" if run.holds_run() else "without --resume, a new run starts"))
    if not args.resume and run.holds_run() and not args.force and group.writes:
        held = ", ".join(run.run_files())
        if missing:
            raise InputError(run.path, f"holds a run that cannot be resumed ({held}; no {missing}): replace it with "
                                       "--force")
        raise InputError(run.path, f"holds another run ({held}): continue it with --resume, or replace it with --force")
    scene_for_training(args, group.size)   # a folder of photos: SfM makes its scene first (or made it before)
    cfg = train_config(args, run, group.size)
    # before anything is sized by them: ranks started with other settings corrupted each other's memory
    given = {"out": str(run.path.resolve()), "resume": args.resume, "force": args.force}
    group.check_same_settings({**{name: setting_value(cfg, name) for name in SETTINGS}, **given},
                              {**FLAG_OF, **{name: f"--{name}" for name in given}})
    scene = run.load_scene(cfg)
    run.check_not_the_scene(scene)
    scene.read_all_images()
    # stage times go to metrics.jsonl; no measurable cost on PoCL
    rt = Runtime(device_of_process(group, args.device), profiling=True)
    trainer = Trainer(cfg, scene, rt, run, check_finite=args.check_finite, lpips=lpips_metric(args.lpips), group=group)
    if not group.writes:   # a parallel run's other processes: train, say nothing
        return _follow(trainer, args)
    live = None
    if args.viewer:   # before anything is written: a port in use stops the command
        from ..render import Renderer
        live = Viewer(rt, Renderer(rt, options=trainer.renderer.context.options), scene.train, port=args.port,
                      background=scene.background, images=scene.image, points=scene.points)
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
          f"test views, {view_sizes(scene.train + scene.test)}{lens_models(scene.train + scene.test)}), strategy "
          f"{trainer.strategy.label}, "
          f"{cfg.iterations:,} iterations, {trainer.model.n:,} initial Gaussians\noutput: {run}", file=sys.stderr)
    if group.size > 1:
        print("stop: SIGUSR1 to mpirun stops every process after a checkpoint (SIGTERM or Ctrl-C to it "
              "ends them at once: the run then resumes from its last checkpoint)", file=sys.stderr)
    if trainer.cap is not None:
        print(f"cap: {trainer.cap:,} Gaussians: {trainer.cap_memory(rt)}", file=sys.stderr)
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
              f"{group.reduce_seconds / done * 1e3:.1f} ms an iteration (device to host, MPI Allreduce, "
              f"host to device; {group.reduce_seconds / max(seconds, 1e-9):.0%} of the training time)")
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
    from ..train import Stopped
    if args.resume:
        trainer.resume()
    try:
        trainer.run(progress="none")
    except Stopped as e:
        return 128 + e.signum
    return 0
