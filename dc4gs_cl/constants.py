"""Numeric constants of the rasterizer and the training recipe, defined once.

The kernels receive the rasterizer's constants as -D options built by `kernel_defines()`, so the host, the
NumPy references and the device never disagree. Values follow the Inria 3DGS release and gsplat
(see ../shared/docs/conventions.md).
"""
from __future__ import annotations

import math

TILE_SIZE = 16                 # pixels per tile side
NEAR_PLANE = 0.2               # cull a Gaussian whose view-space depth is <= this
EWA_DILATION = 0.3             # px^2 added to the 2D covariance's diagonal (low-pass filter)
ANTIALIAS_GRAD_EPS = 1e-6      # antialiased mode: d compensation / d its square = 0.5 / (compensation + this), as
                               # gsplat's, finite for a Gaussian thin enough that its compensation is 0
FOV_CLAMP = 1.3                # x/z, y/z clamped to this times the half-field-of-view tangent
FISHEYE_SERIES_R2 = 1e-2       # a fisheye's radial profile by its Taylor series below this |u|^2 (float32 cancels)
RADIUS_SIGMAS = 3.0            # screen radius = ceil(RADIUS_SIGMAS * sqrt(largest eigenvalue))
MIN_EIGEN_GAP = 0.1            # lambda_max = mid + sqrt(max(MIN_EIGEN_GAP, mid^2 - det))
ALPHA_MAX = 0.99               # alpha = min(ALPHA_MAX, opacity * exp(power))
ALPHA_MIN = 1.0 / 255.0        # a pair with smaller alpha is skipped
TRANSMITTANCE_MIN = 1e-4       # stop before blending a Gaussian that would push T below this
ALPHA_EXTENT_MARGIN = 0.01     # px added to the reach where alpha can reach ALPHA_MIN (float32 rounding)
MIN_SPLIT_LINE_PX = 0.01       # DCS: a principal axis projecting shorter than this separates no pixels
QUAT_NORM_MIN = 1e-15          # a quaternion shorter than this is the identity rotation (and gets no gradient):
                               # its squared norm stays a normal float32, where the inverse square root is exact
COLOR_MAX = 1e4                # a Gaussian's colour is clamped to [0, COLOR_MAX]: far above any trained colour,
                               # low enough that the loss's fourth powers of pixel values stay finite in float32
# A model's values as read (ply.read_ply) and exported: trained ones lie far inside; beyond, float32 overflows in
# the kernels' covariances (a scale's square) or an export's exp(log scale), or a camera's transform of the mean.
MAX_ABS_LOG_SCALE = 40.0         # |log scale|: e^40 ~ 2e17 px-sized scales square to 5e34 < float32's 3.4e38
MAX_ABS_MEAN = 1e15              # |mean| in scene units: a rotation and translation of it stay far below overflow

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)
SH_MAX_DEGREE = 3
MCMC_NOISE_K, MCMC_NOISE_X0 = 100.0, 0.995   # MCMC's noise gate 1 / (1 + exp(-k ((1 - opacity) - x0))): gsplat's
LAMBDA_DSSIM = 0.2             # the training loss L = (1 - LAMBDA_DSSIM) L1 + LAMBDA_DSSIM (1 - SSIM): the default

# A frame's counts on the device, uint words (render/isect.py starts them in StageContext.frame): the visible
# Gaussians, the depth keys' range, the pairs, the Gaussians whose pairs span the backward's runs
# (backward/sum_pairs.py), and whether the pairs overflowed the capacity the frame was given or those Gaussians
# its carry rows (then the kernels that change the model, its moments, the window or the loss' sums leave them as
# they were, and the trainer runs the iteration again with room: train/trainer.py). Kernels see FRAME_<WORD> = its
# index.
FRAME_WORDS = ("VISIBLE", "DEPTH_KEY_MIN", "DEPTH_KEY_MAX", "PAIRS", "SPANNING", "OVERFLOWED")
# OVERFLOWED's bits: which room was short (kernels/isect.cl sets the first, sum_pairs.cl run_spans the second)
PAIRS_OVERFLOWED, CARRY_OVERFLOWED = 1, 2
# count_at of a kernel that takes its element count from the device (kernels/runs.h element_count) when the host
# knows the count (the bound itself) and no count is to be read
HOST_COUNT = 0xFFFFFFFF


def tile_grid(width: int, height: int) -> tuple[int, int]:
    """Tiles across and down an image of width x height pixels."""
    return -(-width // TILE_SIZE), -(-height // TILE_SIZE)


def sh_coeffs(degree: int) -> int:
    """Number of SH coefficients per colour channel for a degree (1, 4, 9, 16)."""
    return (degree + 1) ** 2


def sh_degree_of(coeffs: int) -> int:
    """The SH degree that has this many coefficients per channel (the inverse of sh_coeffs)."""
    return math.isqrt(coeffs) - 1


def kernel_defines() -> dict[str, int | float | str]:
    """The constants every kernel sees, as -D name=value pairs (the runtime writes floats as C float literals)."""
    d: dict[str, int | float | str] = {
        "TILE_SIZE": TILE_SIZE, "NEAR_PLANE": NEAR_PLANE, "EWA_DILATION": EWA_DILATION, "FOV_CLAMP": FOV_CLAMP,
        "FISHEYE_SERIES_R2": FISHEYE_SERIES_R2,
        "ANTIALIAS_GRAD_EPS": ANTIALIAS_GRAD_EPS,
        "RADIUS_SIGMAS": RADIUS_SIGMAS, "MIN_EIGEN_GAP": MIN_EIGEN_GAP, "ALPHA_MAX": ALPHA_MAX,
        "ALPHA_MIN": ALPHA_MIN, "TRANSMITTANCE_MIN": TRANSMITTANCE_MIN,
        "ALPHA_EXTENT_MARGIN": ALPHA_EXTENT_MARGIN, "MIN_SPLIT_LINE_PX": MIN_SPLIT_LINE_PX,
        "COLOR_MAX": COLOR_MAX, "MAX_ABS_MEAN": MAX_ABS_MEAN,
        "QUAT_NORM2_MIN": QUAT_NORM_MIN ** 2, "SH_C0": SH_C0, "SH_C1": SH_C1,
    }
    d.update({f"SH_C2_{i}": c for i, c in enumerate(SH_C2)})
    d.update({f"SH_C3_{i}": c for i, c in enumerate(SH_C3)})
    d.update({f"FRAME_{word}": i for i, word in enumerate(FRAME_WORDS)})
    d["HOST_COUNT"] = f"{HOST_COUNT:#x}u"
    d["PAIRS_OVERFLOWED"], d["CARRY_OVERFLOWED"] = f"{PAIRS_OVERFLOWED}u", f"{CARRY_OVERFLOWED}u"
    return d
