"""Inputs for tests and benchmarks: random Gaussians and cameras, and the gsplat test asset."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..constants import sh_coeffs
from ..model import GaussianModel, logit, rgb_to_sh_dc
from ..scene.camera import Camera
from ..scene.distortion import DIRECT_MODELS, from_colmap


def random_model(rng: np.random.Generator, n: int, sh_degree: int = 3, spread: float = 1.0,
                 scale_range=(0.005, 0.08)) -> GaussianModel:
    """n Gaussians uniform in [-spread, spread]^3 with random shapes, opacities and SH colours."""
    k = sh_coeffs(sh_degree)
    return GaussianModel(
        means=rng.uniform(-spread, spread, (n, 3)),
        log_scales=np.log(rng.uniform(*scale_range, (n, 3))),
        quats=rng.normal(size=(n, 4)),
        opacity_logits=rng.normal(0, 1.5, n),
        sh=rng.normal(0, 0.4, (n, k, 3)))


def random_camera(rng: np.random.Generator, width: int, height: int, distance: float = 2.5) -> Camera:
    """A camera on a sphere around the origin looking near it, with an off-centre principal point."""
    d = rng.normal(size=3)
    eye = distance * d / np.linalg.norm(d)
    cam = Camera.look_at("random", eye, rng.uniform(-0.2, 0.2, 3), width, height, fov_x=rng.uniform(0.6, 1.2))
    return replace(cam, fy=cam.fx * rng.uniform(0.9, 1.1), cx=cam.cx + rng.uniform(-5, 5),
                   cy=cam.cy + rng.uniform(-5, 5))


def gsplat_test_garden(path: str | Path, rng: np.random.Generator) -> tuple[GaussianModel, list[Camera]]:
    """gsplat's test asset (a point cloud of Mip-NeRF 360 "garden" with 3 cameras) turned into Gaussians
    the way gsplat's tests do: points cropped to [-2, 2]^3, scales uniform in [1e-4, 0.02], random unit
    quaternions, opacities uniform in (0, 1); colours become SH degree 0."""
    data = np.load(Path(path))
    means = data["means3d"].astype(np.float64)
    keep = ((means >= -2) & (means <= 2)).all(axis=1)
    means, colors = means[keep], data["colors"][keep] / 255.0
    n = len(means)
    quats = rng.normal(size=(n, 4))
    model = GaussianModel(means=means, log_scales=np.log(rng.uniform(1e-4, 0.02, (n, 3))),
                          quats=quats / np.linalg.norm(quats, axis=1, keepdims=True),
                          opacity_logits=logit(rng.uniform(0.01, 0.99, n)), sh=rgb_to_sh_dc(colors)[:, None, :])
    width, height = int(data["width"]), int(data["height"])
    cams = [Camera(f"garden_{i}", width, height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                   V[:3, :3].astype(np.float64), V[:3, 3].astype(np.float64))
            for i, (V, K) in enumerate(zip(data["viewmats"], data["Ks"]))]
    return model, cams


# Lenses for tests and benchmarks: a COLMAP model, its distortion coefficients in COLMAP's order after the
# intrinsics, and the factor on the pinhole's focal lengths (the fisheye sees a wider field).
LENSES = {
    "opencv": ("OPENCV", (-0.25, 0.08, 0.002, -0.001), 1.0),
    "full_opencv": ("FULL_OPENCV", (-0.3, 0.1, 0.001, 0.002, 0.02, 0.05, 0.01, 0.003), 1.0),
    "fisheye": ("OPENCV_FISHEYE", (0.05, -0.02, 0.004, -0.001), 0.7),
}


def distorted_camera(cam: Camera, lens: str) -> Camera:
    """`cam` with one of LENSES (its focal lengths scaled by the lens' factor), as a scene reader makes it."""
    model, coefficients, focal = LENSES[lens]
    names, _ = DIRECT_MODELS[model]
    given = {"f": cam.fx * focal, "fx": cam.fx * focal, "fy": cam.fy * focal, "cx": cam.cx, "cy": cam.cy}
    params = [given[n] for n in names if n in given] + list(coefficients)
    (fx, fy, cx, cy), dist = from_colmap(model, params, cam.width, cam.height, None, cam.name)
    return replace(cam, fx=fx, fy=fy, cx=cx, cy=cy, distortion=dist)
