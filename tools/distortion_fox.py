"""A distorted capture trained through its lens model against undistorted to pinholes (--undistort), same seeds,
scored on the same pixels: the original test photos, each model rendered through the photo's own camera model.

    python tools/distortion_fox.py [--scene ../shared/data/fox] [-r 8] [--iterations 2000] [--seeds 0 1]

Per run: PSNR over the whole test photos, PSNR over their pixels that the undistorted pinhole image keeps (its crop:
the pixels whose ray lands inside the undistorted camera's image), and the undistorted run's PSNR on its own
undistorted test images (what `train --undistort` reports).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench_train import DATA   # the shared data folder beside the repository
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.camera import Camera
from dc4gs_cl.scene.distortion import undistort_points
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.train.trainer import Trainer

FOX = DATA / "fox"


def kept_by_undistortion(cam: Camera, pinhole: Camera) -> np.ndarray:
    """(H, W) bool: the pixels of the distorted camera whose ray lies inside the undistorted pinhole's image."""
    jj, ii = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    d = np.stack([(ii - cam.cx) / cam.fx, (jj - cam.cy) / cam.fy], -1)
    u = undistort_points(cam.distortion, d)
    x, y = pinhole.fx * u[..., 0] + pinhole.cx, pinhole.fy * u[..., 1] + pinhole.cy
    return (x >= 0) & (x < pinhole.width) & (y >= 0) & (y < pinhole.height)


def psnr(image: np.ndarray, target: np.ndarray, keep: np.ndarray | None = None) -> float:
    err = (np.clip(image, 0, 1) - target) ** 2
    mse = err.mean() if keep is None else err[keep].mean()
    return float(-10 * np.log10(mse))


def train(cfg: TrainConfig, scene, rt: Runtime) -> Trainer:
    trainer = Trainer(cfg, scene, rt)
    for _ in range(cfg.iterations):
        trainer.step()
    return trainer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, default=FOX)
    parser.add_argument("-r", "--resolution", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=2000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--device", default=None)
    args = parser.parse_args()
    rt = Runtime(args.device)
    direct = load_scene(args.scene, resolution=args.resolution)
    undistorted = load_scene(args.scene, resolution=args.resolution, undistort=True)
    pinholes = {c.name: c for c in undistorted.test}
    keep = {c.name: kept_by_undistortion(c, pinholes[c.name]) for c in direct.test}
    cam = direct.test[0]
    print(f"device: {describe(rt.device)}; {args.scene.name}: {len(direct.train)} train / {len(direct.test)} test "
          f"views, {cam.distortion.model}; direct {cam.width}x{cam.height}, undistorted "
          f"{pinholes[cam.name].width}x{pinholes[cam.name].height}; the crop keeps "
          f"{np.mean([k.mean() for k in keep.values()]):.1%} of the photos' pixels; {args.iterations} iterations")
    print(f"{'seed':>4} {'run':<12} {'whole photo':>12} {'crop pixels':>12} {'own images':>11} {'Gaussians':>10} "
          f"{'minutes':>8}")
    for seed in args.seeds:
        for label, scene, undistort in (("direct", direct, False), ("undistorted", undistorted, True)):
            cfg = TrainConfig(scene=str(args.scene), resolution=args.resolution, iterations=args.iterations,
                              seed=seed, undistort=undistort)
            t = time.perf_counter()
            trainer = train(cfg, scene, rt)
            minutes = (time.perf_counter() - t) / 60

            def render(c):
                return trainer.renderer.render(trainer.params, c, trainer.sh_degree, scene.background).image(rt)
            whole = np.mean([psnr(render(c), direct.image(c)) for c in direct.test])
            crop = np.mean([psnr(render(c), direct.image(c), keep[c.name]) for c in direct.test])
            own = np.mean([psnr(render(c), scene.image(c)) for c in scene.test])
            print(f"{seed:>4} {label:<12} {whole:>12.2f} {crop:>12.2f} {own:>11.2f} {trainer.params.n:>10,} "
                  f"{minutes:>8.1f}", flush=True)


if __name__ == "__main__":
    main()
