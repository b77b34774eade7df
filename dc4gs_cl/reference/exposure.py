"""Float64 reference of kernels/exposure.cl (train --exposure): the 3x4 affine colour correction of a photo, its
gradients, the dense Adam step on every photo's correction (in the photos' colour coordinates) and the anchor; and
the corrected metrics' closed-form fit (evaluation/metrics.py's corrected_psnr fits the same affine)."""
from __future__ import annotations

import numpy as np


def apply(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """out = A x + b for a correction T (12 floats, [A | b] row-major) and colours x (..., 3)."""
    M = np.asarray(T, np.float64).reshape(3, 4)
    return np.asarray(x, np.float64) @ M[:, :3].T + M[:, 3]


def backward(T: np.ndarray, x: np.ndarray, g: np.ndarray, keep: np.ndarray | None = None) -> tuple:
    """(dL/dT [12], dL/dx (..., 3)) from g = dL/dout, summed over the pixels keep keeps (all where None); dL/dx is 0
    at masked pixels."""
    M = np.asarray(T, np.float64).reshape(3, 4)
    x, g = np.asarray(x, np.float64).reshape(-1, 3), np.asarray(g, np.float64).reshape(-1, 3)
    if keep is not None:
        g = g * np.asarray(keep, bool).reshape(-1, 1)
    dT = np.concatenate([g.T @ x, g.sum(0)[:, None]], axis=1)   # dL/dA_ij = sum g_i x_j, dL/db_i = sum g_i
    return dT.reshape(12), g @ M[:, :3]


def _coords(coords) -> tuple[np.ndarray, np.ndarray]:
    c = np.concatenate([np.eye(3).reshape(9), np.zeros(3)]) if coords is None else np.asarray(coords, np.float64)
    return c[:9].reshape(3, 3), c[9:]


def from_coords(P: np.ndarray, coords) -> np.ndarray:
    """Corrections T (..., 12) of parameters P (..., 12) in the colour coordinates coords (W [3][3] row-major, then
    mu [3]): out = P_A (W (x - mu)) + P_b, so A = P_A W and b = P_b - A mu (linear in P)."""
    W, mu = _coords(coords)
    P = np.asarray(P, np.float64).reshape(-1, 3, 4)
    T = np.empty_like(P)
    T[:, :, :3] = P[:, :, :3] @ W
    T[:, :, 3] = P[:, :, 3] - T[:, :, :3] @ mu
    return T.reshape(-1, 12)


def coords_gradient(grad: np.ndarray, coords) -> np.ndarray:
    """dL/dP [12] in the colour coordinates from dL/dT [12]: (dL/dA - dL/db mu^T) W^T and dL/db."""
    W, mu = _coords(coords)
    g = np.asarray(grad, np.float64).reshape(3, 4)
    return np.concatenate([(g[:, :3] - np.outer(g[:, 3], mu)) @ W.T, g[:, 3:]], axis=1).reshape(12)


def adam_anchor(T, m, v, view: int, grad, lr: float, t: int, coords=None, b1=0.9, b2=0.999, eps=1e-15) -> tuple:
    """One Adam step (PyTorch's rule) on every photo's T [photos][12], photo `view`'s gradient `grad` (dL/dT), the
    others' zero, taken in the colour coordinates coords (None: T's own; m and v are theirs); then the mean
    deviation from the identity subtracted from each. Returns T, m, v."""
    g = np.zeros(np.shape(T))
    g[view] = coords_gradient(grad, coords)
    m = b1 * np.asarray(m, np.float64) + (1 - b1) * g
    v = b2 * np.asarray(v, np.float64) + (1 - b2) * g * g
    T = np.asarray(T, np.float64) - from_coords((lr / (1 - b1 ** t)) * m / (np.sqrt(v / (1 - b2 ** t)) + eps), coords)
    return T - (T.mean(0) - np.eye(3, 4).reshape(12)), m, v
