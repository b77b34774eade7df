"""What each export format costs: file size, and the PSNR of views rendered from the model read back from
the file against the same views rendered from the model itself (and against the ground truth), as a
markdown table.

    python tools/bench_export.py RUN [--iteration N] [--device D]
    python tools/bench_export.py --ply FILE [--scene SCENE] [--device D]

RUN: a training output folder: its saved model (the last, or --iteration) and its scene's test views (its
training views when it holds none out). --ply: a 3DGS PLY, seen from --scene's test views (default: the
built-in scene). Each format is written to a temporary folder and read back with dc4gs_cl.apps.export's readers,
which decode as the formats' reference readers do; a read-back model renders with the SH degree its file
holds (.splat: colour only, as its viewers show it).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from dc4gs_cl.apps.export import FORMATS, READERS, export_model
from dc4gs_cl.evaluation.metrics import psnr
from dc4gs_cl.ply import read_ply
from dc4gs_cl.render import DeviceGaussians, Renderer
from dc4gs_cl.run_folder import RunFolder
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.builtin import BUILTIN_SCENE


def load(args):
    """(what was measured, the model, the scene, its cameras)."""
    if args.ply is not None:
        scene = load_scene(args.scene)
        return str(args.ply), read_ply(args.ply), scene, scene.test or scene.train
    run = RunFolder(args.run)
    iteration, model = run.load_model(args.iteration)
    scene = run.load_scene()
    return f"{run} (iteration {iteration})", model, scene, scene.test or scene.train


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("run", nargs="?", type=Path, help="a training output folder")
    source.add_argument("--ply", type=Path, help="a 3DGS PLY (seen from --scene's views)")
    p.add_argument("--iteration", type=int, default=None, help="with RUN: which saved iteration (default: the last)")
    p.add_argument("--scene", default=BUILTIN_SCENE, help="with --ply: the scene whose test views to render")
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    what, model, scene, cams = load(args)
    rt = Runtime(args.device)
    renderer = Renderer(rt)

    def renders(m):
        g = DeviceGaussians(rt, m)
        return [renderer.render(g, cam, background=scene.background).image(rt) for cam in cams]
    original = renders(model)
    truth = [scene.image(cam) for cam in cams]
    rows = [("original model", "", "", "", "", f"{np.mean([psnr(a, b) for a, b in zip(original, truth)]):.2f}")]
    with tempfile.TemporaryDirectory() as tmp:
        ply_size = None
        for fmt, (suffix, _) in FORMATS.items():
            path = Path(tmp) / f"model{suffix}"
            export_model(model, path)
            size = path.stat().st_size
            ply_size = ply_size or size   # "ply" comes first
            images = renders(READERS[fmt](path))
            vs_original = [psnr(a, b) for a, b in zip(images, original)]
            rows.append((fmt, f"{size / 1e6:.2f}", f"{size / len(model):.1f}", f"{size / ply_size:.1%}",
                         "identical" if np.isinf(vs_original).all()
                         else f"{np.mean(vs_original):.2f} / {np.min(vs_original):.2f}",
                         f"{np.mean([psnr(a, b) for a, b in zip(images, truth)]):.2f}"))
    print(f"{what}: {len(model):,} Gaussians, SH degree {model.sh_degree}; {len(cams)} views of "
          f"{cams[0].width}x{cams[0].height}; device {describe(rt.device)}\n")
    print("| format | MB | bytes / Gaussian | of the PLY | PSNR vs the model's renders, dB (mean / worst view) "
          "| PSNR vs ground truth, dB |")
    print("|---|--:|--:|--:|--:|--:|")
    for row in rows:
        print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
