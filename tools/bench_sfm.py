"""SfM benchmark: each shared COLMAP scene's photos, copied without their model (scaled to --width where given),
made into a scene by dc4gs-cl's SfM (scene/sfm.py), against the model the scene ships.

    python tools/bench_sfm.py [--scenes S ...] [--width W] [--max-features N] [--exhaustive-up-to N]
                              [--camera-model M] [--affine-shape] [--train N] [--data DIR] [--json PATH] [--keep DIR]

Per scene: each stage's wall time (features, matching, mapping; writing the scene is in "total"), the registered
fraction, the models' photo counts, and the alignment error: the largest distance of a registered camera centre
from the shipped model's after the best similarity (Umeyama), over the shipped cameras' extent (1.1 x their
largest distance from their mean). fountain_p11 and temple_sparse_ring ship ground-truth poses, sceaux_castle and
beer COLMAP's. --train N also trains N iterations on the recovered and on the shipped scene (same settings, same
seed, the photos as shipped: no --width) and gives the test views' PSNR of each.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dc4gs_cl.geometry import similarity_alignment  # noqa: E402
from dc4gs_cl.scene.sfm import Progress, camera_centres, make_scene  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data"
SCENES = ("fountain_p11", "temple_sparse_ring", "sceaux_castle", "beer")


def copy_photos(source: Path, out: Path, width: int | None) -> None:
    out.mkdir(parents=True)
    for p in sorted(source.iterdir()):
        buf = oiio.ImageBuf(str(p))
        if width is None or width >= buf.spec().width:
            shutil.copy(p, out / p.name)
            continue
        height = round(buf.spec().height * width / buf.spec().width)
        if not oiio.ImageBufAlgo.resize(buf, roi=oiio.ROI(0, width, 0, height, 0, 1, 0, 3)).write(str(out / p.name)):
            raise RuntimeError(f"{out / p.name}: {oiio.geterror()}")


def alignment_error(centres: dict, reference: dict) -> float | None:
    names = sorted(n for n in centres if n in reference)
    if len(names) < 3:
        return None
    X, Y = np.array([centres[n] for n in names]), np.array([reference[n] for n in names])
    s, R, t = similarity_alignment(X, Y)
    extent = 1.1 * np.linalg.norm(Y - Y.mean(axis=0), axis=1).max()
    return float(np.linalg.norm(s * X @ R.T + t - Y, axis=1).max() / extent)


def train_psnr(scene: Path, run: Path, iterations: int) -> float:
    subprocess.run([sys.executable, "-m", "dc4gs_cl", "train", "--scene", str(scene), "--out", str(run),
                    "--iterations", str(iterations), "--no-progress", "--lpips", "none", "-r", "1"],
                   check=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True)
    return json.loads((run / "results.json").read_text())[f"ours_{iterations}"]["PSNR"]


def bench(name: str, args, work: Path) -> dict:
    photos = work / name / "images"
    copy_photos(args.data / name / "images", photos, args.width)
    given = {k: v for k in ("max_features", "exhaustive_up_to", "camera_model", "affine_shape")
             if (v := getattr(args, k)) is not None}
    start = time.perf_counter()
    result = make_scene(photos.parent, None, given, Progress("lines"))
    total = time.perf_counter() - start
    reference = camera_centres(args.data / name / "sparse" / "0")
    row = {"scene": name, "photos": result.photos, "width": oiio.ImageInput.open(str(photos / sorted(
        os.listdir(photos))[0])).spec().width, "registered": result.models[0], "models": result.models,
        "seconds": {**{k: round(v, 2) for k, v in result.seconds.items()}, "total": round(total, 2)},
        "alignment_error": alignment_error(camera_centres(photos.parent / "sparse" / "0"), reference)}
    if args.train:
        row["psnr_recovered"] = train_psnr(photos.parent, work / f"{name}-run-recovered", args.train)
        row["psnr_shipped"] = train_psnr(args.data / name, work / f"{name}-run-shipped", args.train)
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", nargs="+", default=list(SCENES))
    p.add_argument("--width", type=int, default=None, help="photos scaled to this width (default: as shipped)")
    p.add_argument("--max-features", type=int, default=None)
    p.add_argument("--exhaustive-up-to", type=int, default=None)
    p.add_argument("--camera-model", default=None)
    p.add_argument("--affine-shape", action="store_true", default=None)
    p.add_argument("--train", type=int, default=0, metavar="N", help="also train N iterations on both scenes")
    p.add_argument("--data", type=Path, default=DEFAULT_DATA, help=f"the shared scenes (default {DEFAULT_DATA})")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--keep", type=Path, default=None, help="make the scenes here (default: a temporary folder)")
    args = p.parse_args()
    if args.train and args.width:
        p.error("--train compares with the shipped scene, at its size: no --width")
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench-sfm-"))
    rows = []
    for name in args.scenes:
        rows.append(bench(name, args, work))
        print(json.dumps(rows[-1]), file=sys.stderr)
    print(f"{os.cpu_count()} cores ({platform.processor() or platform.machine()})\n")
    print("| scene | photos | width | registered | models | features s | matching s | mapping s | total s | "
          "alignment error | PSNR recovered / shipped |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        s, err = r["seconds"], r["alignment_error"]
        psnr = f"{r['psnr_recovered']:.2f} / {r['psnr_shipped']:.2f}" if "psnr_shipped" in r else ""
        print(f"| {r['scene']} | {r['photos']} | {r['width']} | {r['registered']} | {r['models']} | {s['features']} | "
              f"{s['matching']} | {s['mapping']} | {s['total']} | "
              f"{'n/a' if err is None else f'{err:.2%}'} | {psnr} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
