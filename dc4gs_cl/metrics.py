"""Image quality metrics for evaluation: PSNR (host), SSIM (device, the training loss's kernels) and a
note on LPIPS. Images are (H, W, 3) float arrays; both metrics clamp them to [0, 1] first."""
from __future__ import annotations

import numpy as np

from .backward.loss import Loss
from .render.stage import StageContext
from .runtime import Runtime


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


def lpips_available() -> tuple[None, str]:
    """LPIPS is not offered: it needs VGG network weights (and a network runtime) that this project
    neither ships nor downloads. Returns (None, the reason) so callers report it instead of failing."""
    return None, ("LPIPS not computed: it needs pretrained VGG weights, which dc4gs-cl does not ship or "
                  "download; compute it with the `lpips` package on the saved test renders")
