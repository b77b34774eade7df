"""Image quality metrics for evaluation: PSNR (host), SSIM (device, the training loss's kernels) and LPIPS
(host, lpips.py) where its weights are installed. Images are (H, W, 3) float arrays; every metric clamps them to
[0, 1] first."""
from __future__ import annotations

import numpy as np

from ..backward.loss import Loss
from ..errors import InputError
from ..render.stage import StageContext
from ..runtime import Runtime
from .lpips import DEFAULT_LPIPS, Lpips, LpipsUnavailable


def _clamped(image) -> np.ndarray:
    return np.clip(np.asarray(image, np.float32), 0.0, 1.0)


def psnr(image, target) -> float:
    """10 log10(1 / MSE) over pixels and channels; inf for identical images."""
    mse = float(np.mean((_clamped(image).astype(np.float64) - _clamped(target)) ** 2))
    return float("inf") if mse == 0.0 else 10.0 * np.log10(1.0 / mse)


def ssim(rt: Runtime, image, target) -> float:
    """Mean SSIM (11 x 11 Gaussian window, zero padding, per channel) computed by kernels/loss.cl."""
    x, y = _clamped(image), _clamped(target)
    if x.shape != y.shape or x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"images must both be (H, W, 3), got {x.shape} and {y.shape}")
    loss = Loss(StageContext(rt))
    loss(rt.to_device(x), rt.to_device(y), x.shape[1], x.shape[0], None, stage="metrics")
    return loss.read_stats()["ssim"]


def fit_affine(image, target) -> np.ndarray:
    """The 3 x 4 [A | b] minimising the squared error of A rgb + b against the target over the pixels (float64
    least squares, the images clamped as scored)."""
    x = _clamped(image).reshape(-1, 3).astype(np.float64)
    y = _clamped(target).reshape(-1, 3).astype(np.float64)
    solution, *_ = np.linalg.lstsq(np.column_stack([x, np.ones(len(x))]), y, rcond=None)
    return solution.T


def corrected_halves(image, target) -> tuple[np.ndarray, np.ndarray]:
    """The Inria code's corrected-metrics protocol: a colour correction (fit_affine) fitted on the view's left half
    (columns < W / 2), applied to its right half; (the corrected right half of the render, the target's)."""
    half = np.asarray(image).shape[1] // 2
    M = fit_affine(np.asarray(image)[:, :half], np.asarray(target)[:, :half])
    right = _clamped(image)[:, half:].astype(np.float64)
    return (right @ M[:, :3].T + M[:, 3]).astype(np.float32), np.asarray(target)[:, half:]


def lpips_metric(choice: str | None):
    """(an lpips.Lpips or None, a note for the output). choice None: VGG where its weights are installed, else
    skipped with a line saying how to install them; "vgg" / "alex": that network, its weights required (an
    InputError where they are missing); "none": skipped."""
    if choice == "none":
        return None, "LPIPS off (--lpips none)"
    try:
        return Lpips(choice or DEFAULT_LPIPS), f"LPIPS ({choice or DEFAULT_LPIPS})"
    except LpipsUnavailable as e:
        if choice is None:
            return None, f"LPIPS skipped: {e}"
        raise InputError(None, f"--lpips {choice}: {e}") from None
