"""What rendering through a lens model costs: the projection's forward and backward kernels (project.cl,
project_backward.cl) for a pinhole and for each lens of reference.testing.LENSES, on the same random Gaussians and
pose, and a whole training iteration on the built-in scene through each.

    python tools/bench_distortion.py [--gaussians 200000] [--runs 7] [--device D]

Kernel times are medians of --runs launches from OpenCL profiling events; the iteration's the median wall time of
--runs x 10 frozen training steps (no densification, so every step trains the same model).
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from dc4gs_cl.backward import ProjectBackward
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.model import group_widths
from dc4gs_cl.reference.testing import LENSES, distorted_camera, random_camera, random_model
from dc4gs_cl.render import DeviceGaussians, Renderer
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.statistics import GRADIENTS
from dc4gs_cl.train.trainer import Trainer

STEPS_PER_RUN = 10


def kernel_times(rt: Runtime, n: int, runs: int, rng: np.random.Generator) -> None:
    model = random_model(rng, n, sh_degree=3, spread=2.0)
    base = random_camera(rng, 1280, 720, distance=3.5)
    g = DeviceGaussians(rt, model)
    renderer = Renderer(rt)
    backward = ProjectBackward(renderer.context)
    sums = rt.to_device(rng.normal(size=(n, GRADIENTS.width)).astype(np.float32))
    grads = {k: rt.to_device(np.zeros(n * w, np.float32)) for k, w in group_widths(g.sh_coeffs).items()}
    print(f"\nprojection kernels, {n:,} random Gaussians (SH 3), 1280x720; ms, median of {runs}")
    print(f"{'camera':<12} {'visible':>8} {'project':>9} {'backward':>9}")
    for lens in (None, *LENSES):
        cam = base if lens is None else distorted_camera(base, lens)
        res = renderer.render(g, cam, 3)
        forward, back = [], []
        for _ in range(runs):
            rt.stage_times()
            renderer.render(g, cam, 3)
            forward.append(rt.stage_times()["project"])
            backward.gradients(g, cam, 3, res, sums, GRADIENTS, grads)
            back.append(rt.stage_times()["project_backward"])
        visible = int((rt.to_host(res.proj.radius, n, np.int32) > 0).sum())
        print(f"{lens or 'pinhole':<12} {visible:>8,} {np.median(forward) * 1e3:>9.2f} {np.median(back) * 1e3:>9.2f}")


def iteration_times(rt: Runtime, runs: int) -> None:
    scene = load_scene("builtin")
    print(f"\ntraining iteration, built-in scene {scene.train[0].width}x{scene.train[0].height} (frozen: the initial "
          f"Gaussians); ms, median of {runs} x {STEPS_PER_RUN} steps")
    print(f"{'camera':<12} {'iteration':>10} {'project':>9} {'backward':>9}")
    for lens in (None, *LENSES):
        lensed = scene if lens is None else replace(scene, train=[distorted_camera(c, lens) for c in scene.train],
                                                    test=[distorted_camera(c, lens) for c in scene.test])
        lensed.read_all_images()
        trainer = Trainer(TrainConfig(scene="builtin", iterations=10 ** 6), lensed, rt, frozen=True)
        for _ in range(STEPS_PER_RUN):   # builds every kernel
            trainer.step()
        walls, stages = [], []
        for _ in range(runs):
            rt.stage_times()
            t = time.perf_counter()
            for _ in range(STEPS_PER_RUN):
                trainer.step()
            walls.append((time.perf_counter() - t) / STEPS_PER_RUN)
            stages.append(rt.stage_times())
        project = np.median([s["project"] for s in stages]) / STEPS_PER_RUN
        back = np.median([s["project_backward"] for s in stages]) / STEPS_PER_RUN
        print(f"{lens or 'pinhole':<12} {np.median(walls) * 1e3:>10.2f} {project * 1e3:>9.3f} {back * 1e3:>9.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gaussians", type=int, default=200_000)
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--device", default=None)
    args = parser.parse_args()
    rt = Runtime(args.device, profiling=True)
    print(f"device: {describe(rt.device)}")
    kernel_times(rt, args.gaussians, args.runs, np.random.default_rng(0))
    iteration_times(rt, args.runs)


if __name__ == "__main__":
    main()
