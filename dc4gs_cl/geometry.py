"""Rotations and principal axes of Gaussians in float64 NumPy: one module that the host's density control
and the float64 references both use (the kernels have their own, checked against the references)."""
from __future__ import annotations

import numpy as np

from .constants import QUAT_NORM_MIN


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z), any norm (below QUAT_NORM_MIN -> identity) -> (N, 3, 3) rotations."""
    q = np.asarray(q, np.float64)
    n = np.linalg.norm(q, axis=1, keepdims=True)
    rotates = n > QUAT_NORM_MIN
    q = np.where(rotates, q / np.where(rotates, n, 1), np.array([1.0, 0, 0, 0]))
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def principal_axis(log_scales, quats) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(axis index a, sigma = scale along it, world direction p = R e_a); ties take the first axis (as
    kernels/split_geometry.cl does)."""
    s = np.exp(np.asarray(log_scales, np.float64))
    a = np.argmax(s, axis=1)
    rows = np.arange(len(s))
    return a, s[rows, a], quat_to_rotmat(quats)[rows, :, a]
