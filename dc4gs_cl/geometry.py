"""Rotations and principal axes of Gaussians in float64 NumPy: one module that the host's density control
and the float64 references both use (the kernels have their own, checked against the references), and the
camera paths (scene/paths.py)."""
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


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z), w >= 0, of one rotation matrix (Shepperd's method: the largest of the four first)."""
    m = np.asarray(R, np.float64)
    diag = [np.trace(m), m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(diag))
    if k == 0:
        s = 2 * np.sqrt(1 + diag[0])
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i, j, l = k - 1, k % 3, (k + 1) % 3
        s = 2 * np.sqrt(1 + m[i, i] - m[j, j] - m[l, l])
        q = [0.0] * 4
        q[0] = (m[l, j] - m[j, l]) / s
        q[1 + i], q[1 + j], q[1 + l] = 0.25 * s, (m[j, i] + m[i, j]) / s, (m[l, i] + m[i, l]) / s
    q = np.array(q)
    return q if q[0] >= 0 else -q


def slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions along the shorter arc."""
    if np.dot(q0, q1) < 0:
        q1 = -q1
    cos = min(float(np.dot(q0, q1)), 1.0)
    if cos > 1 - 1e-9:   # (nearly) the same rotation: the chord is the arc
        q = (1 - u) * q0 + u * q1
        return q / np.linalg.norm(q)
    theta = np.arccos(cos)
    return (np.sin((1 - u) * theta) * q0 + np.sin(u * theta) * q1) / np.sin(theta)


def principal_axis(log_scales, quats) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(axis index a, sigma = scale along it, world direction p = R e_a); ties take the first axis (as
    kernels/split_geometry.cl does)."""
    s = np.exp(np.asarray(log_scales, np.float64))
    a = np.argmax(s, axis=1)
    rows = np.arange(len(s))
    return a, s[rows, a], quat_to_rotmat(quats)[rows, :, a]


def similarity_alignment(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity (s, R, t) taking the points src (N, 3) nearest to dst (N, 3) in least squares,
    dst ~ s R src + t (Umeyama 1991; R a rotation, never a reflection). Compares SfM's cameras, whose frame and
    scale are arbitrary, with a reference's."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (a ** 2).sum())
    return s, R, md - s * R @ ms
