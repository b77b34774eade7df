"""Evaluation of test views: renders, per-view and mean PSNR and SSIM (run_folder.RunFolder.write_results
stores them as the Inria code does)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from .files import replace_folder, staging_folder
from .metrics import lpips_available, psnr, ssim
from .render import DeviceGaussians, Renderer
from .runtime import Runtime
from .scene.camera import Camera, Scene
from .scene.images import write_png


def evaluate(rt: Runtime, renderer: Renderer, gaussians: DeviceGaussians, scene: Scene, cams: list[Camera],
             sh_degree: int, render_dir: Path | None = None) -> dict:
    """PSNR and SSIM per view and their means; with render_dir, also renders/ and gt/ PNGs there
    (written to a staging folder and moved into place once all views are done)."""
    per_view = {"PSNR": {}, "SSIM": {}}
    staging = staging_folder(render_dir) if render_dir else None
    try:
        for cam in cams:
            image = renderer.render(gaussians, cam, sh_degree, scene.background).image(rt)
            target = scene.image(cam)
            name = f"{cam.file_stem}.png"
            per_view["PSNR"][name] = psnr(image, target)
            per_view["SSIM"][name] = ssim(rt, image, target)
            if staging:
                write_png(staging / "renders" / name, image)
                write_png(staging / "gt" / name, target)
        if staging:
            replace_folder(staging, render_dir)
    finally:
        if staging:
            shutil.rmtree(staging, ignore_errors=True)
    means = {k: float(np.mean(list(v.values()))) if v else float("nan") for k, v in per_view.items()}
    _, why = lpips_available()
    return {"mean": means, "per_view": per_view, "views": len(cams), "lpips": why}


def per_view_lines(result: dict) -> list[str]:
    """One line per test view of an evaluate() result, worst PSNR first (a few bad views, such as extrapolated
    ones full of floaters, move the mean by dBs)."""
    psnrs, ssims = result["per_view"]["PSNR"], result["per_view"]["SSIM"]
    width = max((len(name) for name in psnrs), default=0)
    return [f"  {name:<{width}}  PSNR {psnrs[name]:6.2f} dB  SSIM {ssims[name]:.4f}"
            for name in sorted(psnrs, key=psnrs.get)]
