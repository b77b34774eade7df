"""Evaluation of test views: renders, per-view and mean PSNR, SSIM and (where its weights are installed) LPIPS
(run_folder.RunFolder.write_results stores them as the Inria code does)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from ..files import replace_folder, staging_folder
from ..render import DeviceGaussians, Renderer
from ..run_folder import GROUND_TRUTH, RENDERS
from ..runtime import Runtime
from ..scene.camera import Camera, Scene
from ..scene.images import write_png
from .metrics import corrected_halves, psnr, ssim

CORRECTED = " corrected"   # after a metric's key: scored after the protocol's correction (corrected_halves)


def evaluate(rt: Runtime, renderer: Renderer, gaussians: DeviceGaussians, scene: Scene, cams: list[Camera],
             sh_degree: int, render_dir: Path | None = None, lpips=None, lpips_note: str = "",
             corrected: bool = False) -> dict:
    """PSNR, SSIM and, with an lpips.Lpips, LPIPS per view and their means; with render_dir, also renders/ and
    gt/ PNGs there (written to a staging folder and moved into place once all views are done). lpips_note (from
    metrics.lpips_metric) goes into the result as "lpips", for the output lines. corrected: also "PSNR corrected" and
    "SSIM corrected", each view's right half scored after a colour correction fitted on its left half
    (metrics.corrected_halves, the Inria code's protocol for runs with exposure compensation); the renders are raw."""
    if lpips is not None and not all(lpips.takes(cam.height, cam.width) for cam in cams):
        lpips, lpips_note = None, f"LPIPS skipped: test views too small for its {lpips.net} network"
    per_view = {"PSNR": {}, "SSIM": {}, **({lpips.key: {}} if lpips is not None else {}),
                **({f"PSNR{CORRECTED}": {}, f"SSIM{CORRECTED}": {}} if corrected else {})}
    staging = staging_folder(render_dir) if render_dir else None
    try:
        for cam in cams:
            image = renderer.render(gaussians, cam, sh_degree, scene.background).image(rt)
            target = scene.image(cam)
            name = f"{cam.file_stem}.png"
            per_view["PSNR"][name] = psnr(image, target)
            per_view["SSIM"][name] = ssim(rt, image, target)
            if lpips is not None:
                per_view[lpips.key][name] = lpips.distance(image, target)
            if corrected:
                fixed, right = corrected_halves(image, target)
                per_view[f"PSNR{CORRECTED}"][name] = psnr(fixed, right)
                per_view[f"SSIM{CORRECTED}"][name] = ssim(rt, fixed, right)
            if staging:
                write_png(staging / RENDERS / name, image)
                write_png(staging / GROUND_TRUTH / name, target)
        if staging:
            replace_folder(staging, render_dir)
    finally:
        if staging:
            shutil.rmtree(staging, ignore_errors=True)
    means = {k: float(np.mean(list(v.values()))) if v else float("nan") for k, v in per_view.items()}
    return {"mean": means, "per_view": per_view, "views": len(cams), "lpips": lpips_note,
            "lpips_key": lpips.key if lpips is not None else None}


def summary(result: dict) -> str:
    """The means of an evaluate() result in one phrase: "PSNR 31.20 dB, SSIM 0.9512, LPIPS 0.0811 (vgg)" (or the
    note on why LPIPS is absent)."""
    mean, key = result["mean"], result.get("lpips_key")
    text = f"PSNR {mean['PSNR']:.2f} dB, SSIM {mean['SSIM']:.4f}"
    if key in mean:
        text += f", {result['lpips']} {mean[key]:.4f}"
    elif result.get("lpips"):
        text += f" ({result['lpips']})"
    if f"PSNR{CORRECTED}" in mean:
        text += (f"; corrected (a colour correction fitted on each view's left half, scored on its right): PSNR "
                 f"{mean[f'PSNR{CORRECTED}']:.2f} dB, SSIM {mean[f'SSIM{CORRECTED}']:.4f}")
    return text


def per_view_lines(result: dict) -> list[str]:
    """One line per test view of an evaluate() result, worst PSNR first (a few bad views, such as extrapolated
    ones full of floaters, move the mean by dBs)."""
    psnrs, ssims = result["per_view"]["PSNR"], result["per_view"]["SSIM"]
    lpipss = result["per_view"].get(result.get("lpips_key"), {})
    width = max((len(name) for name in psnrs), default=0)
    fixed = result["per_view"].get(f"PSNR{CORRECTED}", {})
    return [f"  {name:<{width}}  PSNR {psnrs[name]:6.2f} dB  SSIM {ssims[name]:.4f}" +
            (f"  LPIPS {lpipss[name]:.4f}" if name in lpipss else "") +
            (f"  corrected PSNR {fixed[name]:6.2f} dB" if name in fixed else "")
            for name in sorted(psnrs, key=psnrs.get)]
