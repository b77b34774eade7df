"""Float64 references for DC4GS: directional consistency, the split candidates' geometry, and the split
costs exactly as the paper's algorithms 2 and 3 state them (one dot product per candidate and pixel)."""
from __future__ import annotations

import numpy as np

from .. import constants as K
from ..geometry import principal_axis
from ..scene.camera import Camera
from ..scene.distortion import distort


def candidate_points(means, log_scales, quats, n_candidates: int) -> tuple[np.ndarray, np.ndarray]:
    """World positions (G, N, 3) of the N candidates mu + (k - (N-1)/2) * 6 sigma / (N+1) * p, and of the
    axis' end mu + 3 sigma p (G, 3)."""
    _, sigma, p = principal_axis(log_scales, quats)
    step = 6.0 / (n_candidates + 1)
    offsets = (np.arange(n_candidates) - n_candidates // 2) * step
    means = np.asarray(means, np.float64)
    cand = means[:, None] + offsets[None, :, None] * (sigma[:, None] * p)[:, None, :]
    return cand, means + 3 * sigma[:, None] * p


def project_pixels(points, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3) world points -> pixel positions (..., 2) (through the camera's lens model where it has one) and
    depths (...)."""
    pc = np.asarray(points, np.float64) @ cam.R.T + cam.t
    z = pc[..., 2]
    if cam.distortion is not None:
        return distort(cam.distortion, pc[..., :2] / z[..., None]) * [cam.fx, cam.fy] + [cam.cx, cam.cy], z
    return np.stack([cam.fx * pc[..., 0] / z + cam.cx, cam.fy * pc[..., 1] / z + cam.cy], -1), z


def split_geometry_reference(means, log_scales, quats, cam: Camera, visible, n_candidates: int):
    """Candidate and end pixels, and whether the view gives a usable line (visible, all in front of the
    near plane, the projected axis not degenerate)."""
    cand, end = candidate_points(means, log_scales, quats, n_candidates)
    cand_px, cand_z = project_pixels(cand, cam)
    end_px, end_z = project_pixels(end, cam)
    length = np.linalg.norm(end_px - cand_px[:, 0], axis=1)
    valid = (np.asarray(visible) & (cand_z.min(1) > K.NEAR_PLANE) & (end_z > K.NEAR_PLANE)
             & (length > K.MIN_SPLIT_LINE_PX))
    return cand_px, end_px, valid


def directional_consistency(u_sum, count) -> np.ndarray:
    """kappa = |sum of unit vectors| / count; 0 where count is 0 (as a side's cost needs)."""
    count = np.asarray(count, np.float64)
    return np.where(count > 0, np.linalg.norm(u_sum, axis=-1) / np.where(count > 0, count, 1), 0.0)


def side_cost(sums) -> np.ndarray:
    """(..., 5) sums (u_x, u_y, count, |g_x|, |g_y|) of a side -> (1 - kappa) |(sum |g_x|, sum |g_y|)|."""
    sums = np.asarray(sums, np.float64)
    return (1 - directional_consistency(sums[..., :2], sums[..., 2])) * np.linalg.norm(sums[..., 3:5], axis=-1)


def split_costs_from_sums(left, total) -> np.ndarray:
    """(G, N, 5) left-side sums and (G, 5) totals -> J (G, N) = cost(left) + cost(total - left)."""
    left = np.asarray(left, np.float64)
    return side_cost(left) + side_cost(np.asarray(total, np.float64)[:, None, :] - left)
