"""train --exposure on photos whose colours change from photo to photo: the test PSNR (raw: test views rendered
without a correction) of the same run on the unchanged photos and on the changed ones, each without and with
--exposure (same seed and iterations).

    python tools/exposure_study.py [--scene builtin] [-r K] [--iterations 2000] [--seeds 0] [--gain 0.6 1.5]
                                   [--offset 0.1] [--centred] [--unchanged-only] [--device D]

The changed scene: each training photo's colours times a per-channel gain drawn from U(gain) plus a per-channel
offset drawn from U(-offset, offset), drawn per photo from a fixed generator (test photos untouched); not clipped
to [0, 1] (an affine the corrections can undo exactly; a clipped photo loses what no correction brings back).
The change is made here, on the scene the trainer is given: no flag of train's does it.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace

import numpy as np

from dc4gs_cl.config import TrainConfig
from dc4gs_cl.evaluation.evaluate import CORRECTED
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.camera import Scene
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.train import Trainer

CHANGE_SEED = 55   # the photos' gains and offsets (the same for every run and training seed)


def changed_photos(scene: Scene, gain: tuple[float, float], offset: float, centred: bool) -> Scene:
    """The scene with each training photo's colours changed by an affine of its own, the test photos as they are;
    centred: the draws scaled so that the gains' mean is 1 and the offsets' 0 (the test photos are then the
    training photos' average, what the anchored corrections make the model's colours)."""
    rng = np.random.default_rng(CHANGE_SEED)
    gains, offsets = rng.uniform(*gain, (len(scene.train), 3)), rng.uniform(-offset, offset, (len(scene.train), 3))
    if centred:
        gains, offsets = gains / gains.mean(0), offsets - offsets.mean(0)
    change = {cam.name: (g, o) for cam, g, o in zip(scene.train, gains, offsets)}
    kept: dict[str, np.ndarray] = {}

    def read(cam):
        if cam.name not in change:
            return scene.image(cam)
        if cam.name not in kept:
            g, o = change[cam.name]
            kept[cam.name] = (scene.image(cam) * g + o).astype(np.float32)
        return kept[cam.name]
    return replace(scene, read_image=read)


def test_psnr(rt: Runtime, cfg: TrainConfig, scene: Scene) -> tuple[float, float]:
    """The test views' PSNR after training: raw, and corrected (the Inria protocol: evaluate.CORRECTED)."""
    with tempfile.TemporaryDirectory() as out:
        trainer = Trainer(cfg, scene, rt, out)
        trainer.run(progress="none")
        mean = trainer.evaluate_test()["mean"]
        return mean["PSNR"], mean[f"PSNR{CORRECTED}"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="builtin")
    p.add_argument("-r", "--resolution", type=int, default=None)
    p.add_argument("--iterations", type=int, default=2000)
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--gain", type=float, nargs=2, default=(0.6, 1.5))
    p.add_argument("--offset", type=float, default=0.1)
    p.add_argument("--centred", action="store_true", help="the gains' mean 1, the offsets' 0 (changed_photos)")
    p.add_argument("--lr", type=float, nargs=2, default=None, metavar=("INIT", "FINAL"),
                   help="--exposure-lr-init and --exposure-lr-final (default: train's)")
    p.add_argument("--exposure-only", action="store_true",
                   help="only the runs with --exposure (those without do not depend on its settings)")
    p.add_argument("--unchanged-only", action="store_true",
                   help="only the photos as they are (a real capture's own exposure changes)")
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    rt = Runtime(args.device)
    scene = load_scene(args.scene, resolution=args.resolution)
    scenes = {"unchanged": scene}
    if not args.unchanged_only:
        scenes["changed"] = changed_photos(scene, tuple(args.gain), args.offset, args.centred)
    cam = scene.train[0]
    print(f"device: {describe(rt.device)}; scene {args.scene} ({len(scene.train)} train / {len(scene.test)} test "
          f"views, {cam.width}x{cam.height}), {args.iterations} iterations, gains U{tuple(args.gain)}, offsets "
          f"U(-{args.offset}, {args.offset}){', centred' if args.centred else ''}"
          f"{'' if args.lr is None else f', --exposure-lr-init {args.lr[0]:g} --exposure-lr-final {args.lr[1]:g}'}; "
          "test PSNR, dB: raw (corrected), "
          "a column a seed", file=sys.stderr)
    rows = {}
    rates = {} if args.lr is None else {"lr_exposure": args.lr[0], "lr_exposure_final": args.lr[1]}
    for photos, sc in scenes.items():
        for exposure in (True,) if args.exposure_only else (False, True):
            name = f"{photos} photos, {'with' if exposure else 'without'} --exposure"
            rows[name] = np.array([test_psnr(rt, TrainConfig(scene=args.scene, iterations=args.iterations,
                                                             resolution=args.resolution, seed=seed, exposure=exposure,
                                                             corrected_metrics=True, **rates), sc)
                                   for seed in args.seeds])
            print(f"  {name:<40} " + "  ".join(f"{raw:6.2f} ({fixed:6.2f})" for raw, fixed in rows[name]) +
                  f"   mean {rows[name][:, 0].mean():6.2f} ({rows[name][:, 1].mean():6.2f})", flush=True)
    if args.exposure_only:   # the differences need the runs without it
        return 0
    base = rows["unchanged photos, without --exposure"].mean(0)
    for name, values in rows.items():
        raw, fixed = values.mean(0) - base
        print(f"{name:<40} raw {raw:+.2f} dB (corrected {fixed:+.2f} dB) against unchanged photos without --exposure")
    return 0


if __name__ == "__main__":
    sys.exit(main())
