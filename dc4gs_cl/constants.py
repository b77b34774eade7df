"""Numeric constants of the rasterizer and the training recipe, defined once.

The kernels receive the rasterizer's constants as -D options built by `kernel_defines()`, so the host, the
NumPy references and the device never disagree. Values follow the Inria 3DGS release and gsplat
(see ../shared/docs/conventions.md).
"""
from __future__ import annotations

TILE_SIZE = 16                 # pixels per tile side
NEAR_PLANE = 0.2               # cull a Gaussian whose view-space depth is <= this
EWA_DILATION = 0.3             # px^2 added to the 2D covariance's diagonal (low-pass filter)
FOV_CLAMP = 1.3                # x/z, y/z clamped to this times the half-field-of-view tangent
RADIUS_SIGMAS = 3.0            # screen radius = ceil(RADIUS_SIGMAS * sqrt(largest eigenvalue))
MIN_EIGEN_GAP = 0.1            # lambda_max = mid + sqrt(max(MIN_EIGEN_GAP, mid^2 - det))
ALPHA_MAX = 0.99               # alpha = min(ALPHA_MAX, opacity * exp(power))
ALPHA_MIN = 1.0 / 255.0        # a pair with smaller alpha is skipped
TRANSMITTANCE_MIN = 1e-4       # stop before blending a Gaussian that would push T below this

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)
SH_MAX_DEGREE = 3


def sh_coeffs(degree: int) -> int:
    """Number of SH coefficients per colour channel for a degree (1, 4, 9, 16)."""
    return (degree + 1) ** 2


def _c_float(x: float) -> str:
    return f"{x!r}f"


def kernel_defines() -> dict[str, str]:
    """The constants every kernel sees, as -D name=value pairs (floats as C float literals)."""
    d = {
        "TILE_SIZE": str(TILE_SIZE),
        "NEAR_PLANE": _c_float(NEAR_PLANE),
        "EWA_DILATION": _c_float(EWA_DILATION),
        "FOV_CLAMP": _c_float(FOV_CLAMP),
        "RADIUS_SIGMAS": _c_float(RADIUS_SIGMAS),
        "MIN_EIGEN_GAP": _c_float(MIN_EIGEN_GAP),
        "ALPHA_MAX": _c_float(ALPHA_MAX),
        "ALPHA_MIN": _c_float(ALPHA_MIN),
        "TRANSMITTANCE_MIN": _c_float(TRANSMITTANCE_MIN),
        "SH_C0": _c_float(SH_C0),
        "SH_C1": _c_float(SH_C1),
    }
    for i, c in enumerate(SH_C2):
        d[f"SH_C2_{i}"] = _c_float(c)
    for i, c in enumerate(SH_C3):
        d[f"SH_C3_{i}"] = _c_float(c)
    return d
