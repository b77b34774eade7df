"""How far the local Jacobian (kernels/distortion.h, as Brush's) is from the exact lens model, across the field.

Each Gaussian is mapped through the exact model (scene/distortion.distort, float64) point by point: the true mean
and covariance of its image are the moments of its projected points, taken by Gauss-Hermite quadrature (a 20^3
grid of the 3D Gaussian: exact to 1e-9 here, where Monte Carlo's 10^6 samples leave 0.1% noise; --monte-carlo
checks it). The projection's float64 reference (reference/project.py: the centre through the model, the covariance
through its local Jacobian at the centre) is compared with them, for Gaussians along the image's diagonal from the
centre to the corner, each cell the worst of ORIENTATIONS random orientations; the pinhole's rows give the
perspective's own linearisation error, which every EWA splatter has:
  mean px     |mean2d - the true mean|, px
  cov rel     ||Sigma_local - Sigma_true||_F / ||Sigma_true||_F (the EWA dilation taken off)
  box miss    of 10^5 Monte Carlo samples within 3 sigma of the true mean and covariance, the fraction outside the
              kernel's tile box (mean2d +- radius): the tile bounds must cover the distorted footprint
  (radius)    the tile box's half-size, px (the median over the orientations)
Run: PYTHONPATH=$PWD python tools/distortion_error.py [--monte-carlo 1000000]
"""
from __future__ import annotations

import argparse
import numpy as np

from dc4gs_cl import constants as K
from dc4gs_cl.geometry import quat_to_rotmat
from dc4gs_cl.reference.project import project_reference
from dc4gs_cl.reference.testing import LENSES, distorted_camera
from dc4gs_cl.scene.camera import Camera
from dc4gs_cl.scene.distortion import distort, undistort

FIELD = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0)   # fractions of the way from the image's centre to its corner
SIZES_PX = (2.0, 8.0, 32.0)                 # the Gaussian's standard deviation, px, were it at the image's centre
QUADRATURE_NODES = 20                       # Gauss-Hermite nodes per axis
ORIENTATIONS = 8                            # random orientations per cell, the worst reported
COVERAGE_SAMPLES = 10 ** 5


def study(cam: Camera, fraction: float, size_px: float, rng: np.random.Generator, monte_carlo: bool = False,
          samples: int = 10 ** 6) -> dict[str, float]:
    """One Gaussian (an ellipsoid of random orientation, axes 1 : 0.7 : 0.4 of the size) at depth 3 whose centre
    images `fraction` of the way to the corner (pulled in by its 3-sigma radius, so that it stays in the field)."""
    dist, depth = cam.distortion, 3.0
    corner = np.array([cam.width, cam.height], np.float64)
    target = np.array([cam.cx, cam.cy]) + fraction * (corner - [cam.cx, cam.cy])
    d = (target - [cam.cx, cam.cy]) / [cam.fx, cam.fy]
    u = undistort(dist, d, d) if dist is not None else d
    sigma_world = size_px * depth / cam.fx
    scales = sigma_world * np.array([1.0, 0.7, 0.4])
    q = rng.normal(size=4)
    mean_cam = depth * np.array([u[0], u[1], 1.0])
    mean = cam.R.T @ (mean_cam - cam.t)
    ref = project_reference(mean[None], np.log(scales)[None], q[None], np.array([3.0]), np.zeros((1, 1, 3)), cam, 0,
                            *K.tile_grid(cam.width, cam.height))
    conic = ref["conic"][0]
    cov = np.linalg.inv([[conic[0], conic[1]], [conic[1], conic[2]]]) - K.EWA_DILATION * np.eye(2)

    M = quat_to_rotmat(q[None])[0] * scales

    def pixels(normal):   # points of the 3D Gaussian (standard normal coordinates) through the exact model
        pc = (mean + normal @ M.T) @ cam.R.T + cam.t
        uu = pc[:, :2] / pc[:, 2:]
        return (distort(dist, uu) if dist is not None else uu) * [cam.fx, cam.fy] + [cam.cx, cam.cy]

    if monte_carlo:
        px = pixels(rng.normal(size=(samples, 3)))
        true_mean, true_cov = px.mean(0), np.cov(px.T)
    else:
        nodes, weights = np.polynomial.hermite_e.hermegauss(QUADRATURE_NODES)
        grid = np.stack(np.meshgrid(nodes, nodes, nodes, indexing="ij"), -1).reshape(-1, 3)
        w = np.prod(np.stack(np.meshgrid(weights, weights, weights, indexing="ij"), -1).reshape(-1, 3), 1)
        w /= w.sum()
        px = pixels(grid)
        true_mean = w @ px
        true_cov = np.einsum("n,ni,nj->ij", w, px - true_mean, px - true_mean)
    cloud = pixels(rng.normal(size=(COVERAGE_SAMPLES, 3)))
    centred = cloud - true_mean
    inside = np.einsum("ni,ij,nj->n", centred, np.linalg.inv(true_cov), centred) <= K.RADIUS_SIGMAS ** 2
    r = ref["radius"][0]
    outside_box = (np.abs(cloud[inside] - ref["mean2d"][0]) > r).any(axis=1)
    return {"mean px": float(np.linalg.norm(ref["mean2d"][0] - true_mean)),
            "cov rel": float(np.linalg.norm(cov - true_cov) / np.linalg.norm(true_cov)),
            "box miss": float(outside_box.mean()), "radius": float(r)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--monte-carlo", type=int, default=0, metavar="N",
                        help="the true moments from N Monte Carlo samples instead of the quadrature")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    base = Camera.look_at("study", (0.0, -4.0, 0.0), (0.0, 0.0, 0.0), 640, 480, fov_x=1.2)
    how = (f"{args.monte_carlo:,} Monte Carlo samples" if args.monte_carlo
           else f"{QUADRATURE_NODES}^3 Gauss-Hermite nodes")
    print(f"true moments from {how} a Gaussian; 640x480 images; mean px | cov rel | box miss (radius px)")
    for lens in (None, *LENSES):
        cam = base if lens is None else distorted_camera(base, lens)
        print(f"\n{lens or 'pinhole'} (fx {cam.fx:.1f} px)")
        print("field  " + "".join(f"| sigma {s:>4.0f} px {'':22}" for s in SIZES_PX))
        for fraction in FIELD:
            cells = []
            for size in SIZES_PX:
                runs = [study(cam, fraction, size, rng, bool(args.monte_carlo), args.monte_carlo)
                        for _ in range(ORIENTATIONS)]
                worst = {key: max(r[key] for r in runs) for key in runs[0]}
                radius = np.median([r["radius"] for r in runs])
                cells.append(f"| {worst['mean px']:7.3f} {worst['cov rel']:7.4f} {worst['box miss']:8.2e} "
                             f"({radius:4.0f})")
            print(f"{fraction:5.2f}  " + " ".join(cells))


if __name__ == "__main__":
    main()
