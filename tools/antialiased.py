"""What `--antialiased` buys: a scene trained at one resolution with and without it, both evaluated on the test
views at that resolution and at lower ones (zoomed out, where a classic 3DGS model aliases: its Gaussians shrink
below a pixel, and the fixed 0.3 px^2 dilation widens them into bright blobs), one markdown table.

    python tools/antialiased.py [--scene S] [-r K] [--iterations N] [--factors 1 2 4 8] [--seed N] [--device D]

-r is the training resolution (the CLI's -r); each factor f evaluates at -r K*f (1: as trained). Both runs
train with the same seed and recipe in this process (library calls, no run folders) and are evaluated with the
mode they trained in (PSNR and SSIM of dc4gs_cl.evaluation.evaluate; ground truth resized by the scene loader, the
built-in scene's rendered at each size).
"""
from __future__ import annotations

import argparse
import sys
import time

from dc4gs_cl.config import TrainConfig
from dc4gs_cl.evaluation.evaluate import evaluate
from dc4gs_cl.render import Renderer, RenderOptions
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.builtin import BUILTIN_SCENE
from dc4gs_cl.train import Trainer


def train(rt: Runtime, cfg: TrainConfig) -> tuple[Trainer, float]:
    scene = load_scene(cfg.scene, resolution=cfg.resolution)
    scene.read_all_images()
    trainer = Trainer(cfg, scene, rt)
    start = time.perf_counter()
    while trainer.iteration < cfg.iterations:
        trainer.step()
    rt.queue.finish()
    return trainer, time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=BUILTIN_SCENE)
    p.add_argument("-r", "--resolution", type=int, default=1, help="training resolution (-r; default 1)")
    p.add_argument("--iterations", type=int, default=3000)
    p.add_argument("--factors", type=int, nargs="+", default=[1, 2, 4, 8],
                   help="evaluate at -r K times each of these (default 1 2 4 8)")
    p.add_argument("--strategy", default="3dgs")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    rt = Runtime(args.device)
    rows = {}
    for antialiased in (False, True):
        cfg = TrainConfig(scene=args.scene, iterations=args.iterations, resolution=args.resolution,
                          strategy=args.strategy, seed=args.seed, antialiased=antialiased)
        trainer, seconds = train(rt, cfg)
        renderer = Renderer(rt, options=RenderOptions(antialiased=antialiased))
        results = {}
        for factor in args.factors:
            scene = load_scene(args.scene, resolution=args.resolution * factor)
            result = evaluate(rt, renderer, trainer.params, scene, scene.test, trainer.sh_degree)
            size = f"{scene.test[0].width}x{scene.test[0].height}"
            results[factor] = (size, result["mean"]["PSNR"], result["mean"]["SSIM"])
        rows[antialiased] = (trainer.model.n, seconds, results)
        print(f"{'antialiased' if antialiased else 'classic'}: {trainer.model.n:,} Gaussians, {seconds:.0f} s",
              file=sys.stderr)
    print(f"{args.scene}, {args.strategy}, {args.iterations:,} iterations at -r {args.resolution}, seed {args.seed}; "
          f"{describe(rt.device)}\n")
    print("| evaluated at | classic PSNR / SSIM | antialiased PSNR / SSIM | difference (dB) |\n|---|---:|---:|---:|")
    for factor in args.factors:
        size, p0, s0 = rows[False][2][factor]
        _, p1, s1 = rows[True][2][factor]
        label = f"-r {args.resolution * factor} ({size}{', as trained' if factor == 1 else ''})"
        print(f"| {label} | {p0:.2f} / {s0:.4f} | {p1:.2f} / {s1:.4f} | {p1 - p0:+.2f} |")
    print(f"| Gaussians, training time | {rows[False][0]:,}, {rows[False][1]:.0f} s | "
          f"{rows[True][0]:,}, {rows[True][1]:.0f} s | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
