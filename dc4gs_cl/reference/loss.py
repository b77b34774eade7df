"""Float64 reference of kernels/loss.cl: L = (1 - lambda) L1 + lambda (1 - SSIM) and dL/dimage.

Images are (H, W, 3) arrays. SSIM follows the Inria code: per channel, 11 x 11 Gaussian window (sigma 1.5),
zero padding (outside pixels count as 0 in every blurred moment), mean over pixels and channels.
"""
from __future__ import annotations

import numpy as np

from ..backward.loss import SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW
from ..constants import LAMBDA_DSSIM


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """Normalised 1D Gaussian weights, centre at size // 2."""
    t = np.arange(size) - size // 2
    g = np.exp(-t * t / (2.0 * sigma * sigma))
    return g / g.sum()


def blur(img: np.ndarray) -> np.ndarray:
    """Separable zero-padded blur of an (H, W, ...) array with the SSIM window along H, then W."""
    g = gaussian_window()
    r = len(g) // 2
    out = np.asarray(img, np.float64)
    for axis in (0, 1):
        n = out.shape[axis]
        pad = [(0, 0)] * out.ndim
        pad[axis] = (r, r)
        p = np.pad(out, pad)
        out = sum(g[k] * np.take(p, np.arange(k, k + n), axis=axis) for k in range(len(g)))
    return out


def _moments(x, y):
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    mx, my = blur(x), blur(y)
    A = 2 * mx * my + SSIM_C1
    B = 2 * (blur(x * y) - mx * my) + SSIM_C2
    C = mx * mx + my * my + SSIM_C1
    D = blur(x * x) - mx * mx + blur(y * y) - my * my + SSIM_C2
    return mx, my, A, B, C, D


def ssim_map(x, y) -> np.ndarray:
    _, _, A, B, C, D = _moments(x, y)
    return A * B / (C * D)


def masked(x, y, keep=None) -> tuple[np.ndarray, np.ndarray, int]:
    """x and y in float64, zero where keep (H, W) is False, and the number of floats the loss averages over
    (the kept ones; all without a mask)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    if keep is None:
        return x, y, x.size
    k = np.asarray(keep, bool)[..., None]
    return x * k, y * k, max(3 * int(k.sum()), 1)


def loss_value(x, y, lam: float = LAMBDA_DSSIM, keep=None) -> float:
    """The loss, a mean over the pixels keep keeps (all without a mask); masked pixels count as zero in both."""
    x, y, m = masked(x, y, keep)
    return float(((1 - lam) * np.abs(x - y).sum() + lam * (1 - ssim_map(x, y)).sum()) / m)


def loss_gradient(x, y, lam: float = LAMBDA_DSSIM, keep=None) -> np.ndarray:
    """dL/dx. S = AB/(CD) depends on x through mu_x, E[x^2] and E[xy]; the blur is its own adjoint, so
    d mean(S)/dx = (blur(dS/dmu_x) + 2 x blur(dS/dE[x^2]) + y blur(dS/dE[xy])) / M. With a mask, zero at
    masked pixels (x enters as x * keep)."""
    x, y, m = masked(x, y, keep)
    mx, my, A, B, C, D = _moments(x, y)
    S = A * B / (C * D)
    dmu = S * (2 * my / A - 2 * my / B - 2 * mx / C + 2 * mx / D)
    dxx = -S / D
    dxy = 2 * S / B
    dssim = (blur(dmu) + 2 * x * blur(dxx) + y * blur(dxy)) / m
    grad = (1 - lam) * np.sign(x - y) / m - lam * dssim
    return grad if keep is None else grad * np.asarray(keep, bool)[..., None]
