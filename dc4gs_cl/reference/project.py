"""Float64 reference of kernels/project.cl."""
from __future__ import annotations

import numpy as np

from .. import constants as K
from ..scene.camera import Camera


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z), any norm (zero -> identity) -> (N, 3, 3) rotations."""
    q = np.asarray(q, np.float64)
    n = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(n > 0, q / np.where(n > 0, n, 1), np.array([1.0, 0, 0, 0]))
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def sh_basis(degree: int, d: np.ndarray) -> np.ndarray:
    """(N, 3) unit directions -> (N, (degree+1)^2) real SH basis values (the 3DGS convention)."""
    x, y, z = d.T
    cols = [np.full_like(x, K.SH_C0)]
    if degree > 0:
        cols += [-K.SH_C1 * y, K.SH_C1 * z, -K.SH_C1 * x]
    if degree > 1:
        c2 = K.SH_C2
        cols += [c2[0] * x * y, c2[1] * y * z, c2[2] * (2 * z * z - x * x - y * y), c2[3] * x * z,
                 c2[4] * (x * x - y * y)]
    if degree > 2:
        c3 = K.SH_C3
        xx, yy, zz = x * x, y * y, z * z
        cols += [c3[0] * y * (3 * xx - yy), c3[1] * x * y * z, c3[2] * y * (4 * zz - xx - yy),
                 c3[3] * z * (2 * zz - 3 * xx - 3 * yy), c3[4] * x * (4 * zz - xx - yy), c3[5] * z * (xx - yy),
                 c3[6] * x * (xx - 3 * yy)]
    return np.stack(cols, 1)


def tile_rect_reference(mean2d: np.ndarray, half_size: np.ndarray, tiles_x: int, tiles_y: int) -> np.ndarray:
    """(N, 4) int [x0, y0, x1, y1) of the tiles the box mean2d +- half_size (N, 2) px touches."""
    lo = np.floor((mean2d - half_size) / K.TILE_SIZE)
    hi = np.floor((mean2d + half_size) / K.TILE_SIZE) + 1
    grid = np.array([tiles_x, tiles_y])
    return np.concatenate([np.clip(lo, 0, grid), np.clip(hi, 0, grid)], 1).astype(np.int64)


def pair_rect_reference(mean2d, radius, alpha_extent, tiles_x: int, tiles_y: int) -> np.ndarray:
    """The tiles a Gaussian's pairs go to: the 3-sigma box cut down to the box where alpha can reach
    ALPHA_MIN (kernels/common.h, pair_rect)."""
    half = np.minimum(np.asarray(radius, np.float64)[:, None], alpha_extent)
    return tile_rect_reference(np.asarray(mean2d, np.float64), half, tiles_x, tiles_y)


def rect_area(rect: np.ndarray) -> np.ndarray:
    return np.maximum(rect[:, 2] - rect[:, 0], 0) * np.maximum(rect[:, 3] - rect[:, 1], 0)


def project_reference(means, log_scales, quats, opacity_logits, sh, cam: Camera, sh_degree: int,
                      tiles_x: int, tiles_y: int) -> dict[str, np.ndarray]:
    """Per-Gaussian projection in float64; entries other than radius and tiles_touched are meaningful
    only where radius > 0. alpha_extent: half-sizes (px) of the box outside which alpha < ALPHA_MIN."""
    means = np.asarray(means, np.float64)
    R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    pc = means @ R.T + t
    x, y, z = pc.T
    in_front = z > K.NEAR_PLANE
    zs = np.where(in_front, z, 1.0)

    M = quat_to_rotmat(quats) * np.exp(np.asarray(log_scales, np.float64))[:, None, :]
    sigma = M @ M.transpose(0, 2, 1)
    lim_x, lim_y = K.FOV_CLAMP * 0.5 * cam.width / cam.fx, K.FOV_CLAMP * 0.5 * cam.height / cam.fy
    tx, ty = np.clip(x / zs, -lim_x, lim_x), np.clip(y / zs, -lim_y, lim_y)
    J = np.zeros((len(means), 2, 3))
    J[:, 0, 0], J[:, 0, 2] = cam.fx / zs, -cam.fx * tx / zs
    J[:, 1, 1], J[:, 1, 2] = cam.fy / zs, -cam.fy * ty / zs
    T = J @ R
    cov2d = T @ sigma @ T.transpose(0, 2, 1) + K.EWA_DILATION * np.eye(2)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det = a * c - b * b
    ok = in_front & (det > 0)
    dets = np.where(ok, det, 1.0)
    conic = np.stack([c / dets, -b / dets, a / dets], 1)
    mid = 0.5 * (a + c)
    lam = mid + np.sqrt(np.maximum(K.MIN_EIGEN_GAP, mid * mid - det))
    radius = np.where(ok, np.ceil(K.RADIUS_SIGMAS * np.sqrt(np.maximum(lam, 0))), 0)
    mean2d = np.stack([cam.fx * x / zs + cam.cx, cam.fy * y / zs + cam.cy], 1)
    visible = ok & (radius > 0) & (rect_area(tile_rect_reference(mean2d, radius[:, None], tiles_x, tiles_y)) > 0)
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(opacity_logits, np.float64)))
    q = np.where(opacity >= K.ALPHA_MIN, 2 * np.log(np.maximum(opacity, K.ALPHA_MIN) / K.ALPHA_MIN), 0.0)
    alpha_extent = np.sqrt(q[:, None] * np.stack([a, c], 1).clip(0)) + 0.01
    tiles = np.where(visible & (opacity >= K.ALPHA_MIN),
                     rect_area(pair_rect_reference(mean2d, radius, alpha_extent, tiles_x, tiles_y)), 0)

    d = means - cam.center
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    k = (sh_degree + 1) ** 2
    rgb = np.einsum("nk,nkc->nc", sh_basis(sh_degree, d), np.asarray(sh, np.float64)[:, :k]) + 0.5
    return {
        "mean2d": mean2d, "conic": conic, "opacity": opacity, "rgb": np.maximum(rgb, 0.0), "depth": z,
        "radius": np.where(visible, radius, 0).astype(np.int64), "alpha_extent": alpha_extent,
        "tiles_touched": tiles.astype(np.int64),
    }
