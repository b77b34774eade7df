"""Lens distortion rendered directly (kernels/distortion.h): the camera models, their float64 maps and Jacobians,
and the checks that a model can be inverted over its image.

A distorted camera maps the camera-space point (x, y, z) through u = (x/z, y/z) to the distorted normalised point
d = D(u) and the pixel (fx d_x + cx, fy d_y + cy). Both families are radial, with OpenCV's tangential terms:
  D(u) = u rho(|u|^2) + (2 p1 u_x u_y + p2 (|u|^2 + 2 u_x^2), p1 (|u|^2 + 2 u_y^2) + 2 p2 u_x u_y)
  RADIAL_TANGENTIAL (COLMAP SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV):
      rho(s) = (1 + k1 s + k2 s^2 + k3 s^3) / (1 + k4 s + k5 s^2 + k6 s^3)
  FISHEYE (COLMAP OPENCV_FISHEYE, RADIAL_FISHEYE, SIMPLE_RADIAL_FISHEYE; Kannala-Brandt, no tangential terms):
      rho(s) = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) / r,  r = sqrt(s), theta = atan(r)
The parameters do not depend on the image's size (normalised coordinates), so a camera keeps its Distortion at
any -r.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import FOV_CLAMP
from ..errors import InputError

PINHOLE, RADIAL_TANGENTIAL, FISHEYE = 0, 1, 2   # the kernels' -D DISTORTION

# COLMAP model -> (its parameter names, the family); f stands for fx = fy.
DIRECT_MODELS = {
    "SIMPLE_RADIAL": (("f", "cx", "cy", "k1"), RADIAL_TANGENTIAL),
    "RADIAL": (("f", "cx", "cy", "k1", "k2"), RADIAL_TANGENTIAL),
    "OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"), RADIAL_TANGENTIAL),
    "FULL_OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), RADIAL_TANGENTIAL),
    "OPENCV_FISHEYE": (("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"), FISHEYE),
    "RADIAL_FISHEYE": (("f", "cx", "cy", "k1", "k2"), FISHEYE),
    "SIMPLE_RADIAL_FISHEYE": (("f", "cx", "cy", "k1"), FISHEYE),
}
RADIAL_NAMES = ("k1", "k2", "k3", "k4", "k5", "k6")
MAX_FIELD_ANGLE = np.radians(89.0)   # the field's edge is searched up to this angle from the axis
FIELD_SAMPLES = 4096                 # angles sampled for where the radial map stops growing


@dataclass(frozen=True)
class Distortion:
    model: str                     # the COLMAP model it came from
    kind: int                      # RADIAL_TANGENTIAL or FISHEYE
    k: tuple                       # 6 radial coefficients (FISHEYE: k1..k4, then 0, 0)
    p: tuple                       # (p1, p2), tangential (0 for FISHEYE)
    lim: tuple = (np.inf, np.inf)  # |u_x|, |u_y| clamped to these in the covariance's Jacobian (FOV_CLAMP x the field)
    r2_max: float = np.inf         # a centre with |u|^2 beyond this is culled: past it the map may fold back


def radial_profile(kind: int, k, s, series_below: float = 1e-4):
    """rho(s), rho'(s), rho''(s) (derivatives in s = |u|^2), float64, elementwise. FISHEYE below
    `series_below` by its Taylor series in s (the closed form cancels there; the kernel's threshold is larger)."""
    s = np.asarray(s, np.float64)
    if kind == RADIAL_TANGENTIAL:
        k1, k2, k3, k4, k5, k6 = k
        num, dnum, d2num = 1 + s * (k1 + s * (k2 + s * k3)), k1 + s * (2 * k2 + 3 * s * k3), 2 * k2 + 6 * s * k3
        den, dden, d2den = 1 + s * (k4 + s * (k5 + s * k6)), k4 + s * (2 * k5 + 3 * s * k6), 2 * k5 + 6 * s * k6
        rho = num / den
        drho = (dnum - rho * dden) / den
        return rho, drho, (d2num - 2 * drho * dden - rho * d2den) / den
    k1, k2, k3, k4 = k[:4]
    a1, a2, a3 = fisheye_series(k)
    series = (1 + s * (a1 + s * (a2 + s * a3)), a1 + s * (2 * a2 + 3 * s * a3), 2 * a2 + 6 * s * a3)
    ss = np.maximum(s, series_below)
    r = np.sqrt(ss)
    th = np.arctan(r)
    t2 = th * th
    F = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    dF = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    d2F = th * (6 * k1 + t2 * (20 * k2 + t2 * (42 * k3 + t2 * 72 * k4)))
    dth, d2th = 1 / (1 + ss), -2 * r / (1 + ss) ** 2
    rd, drd, d2rd = F, dF * dth, d2F * dth * dth + dF * d2th       # the distorted radius against r
    rho = rd / r
    rho_r = (drd * r - rd) / ss                                     # d rho / dr, d2 rho / dr2
    rho_rr = d2rd / r - 2 * drd / ss + 2 * rd / (ss * r)
    closed = (rho, rho_r / (2 * r), (rho_rr - rho_r / r) / (4 * ss))
    return tuple(np.where(s < series_below, a, b) for a, b in zip(series, closed))


def fisheye_series(k) -> tuple[float, float, float]:
    """rho(s) = 1 + a1 s + a2 s^2 + a3 s^3 + O(s^4) of the FISHEYE profile (atan(r)/r and theta^2 expanded in s)."""
    k1, k2, k3 = k[:3]
    return k1 - 1 / 3, k2 - k1 + 1 / 5, 14 * k1 / 15 - 5 * k2 / 3 + k3 - 1 / 7


def distort(dist: Distortion, u: np.ndarray) -> np.ndarray:
    """(..., 2) undistorted normalised points -> distorted normalised points."""
    x, y = u[..., 0], u[..., 1]
    s = x * x + y * y
    rho = radial_profile(dist.kind, dist.k, s)[0]
    p1, p2 = dist.p
    return np.stack([x * rho + 2 * p1 * x * y + p2 * (s + 2 * x * x),
                     y * rho + p1 * (s + 2 * y * y) + 2 * p2 * x * y], -1)


def distort_jacobian(dist: Distortion, u: np.ndarray) -> np.ndarray:
    """(..., 2, 2) dD/du at undistorted normalised points (..., 2); symmetric."""
    x, y = u[..., 0], u[..., 1]
    rho, drho, _ = radial_profile(dist.kind, dist.k, x * x + y * y)
    p1, p2 = dist.p
    j00 = rho + 2 * x * x * drho + 2 * p1 * y + 6 * p2 * x
    j01 = 2 * x * y * drho + 2 * p1 * x + 2 * p2 * y
    j11 = rho + 2 * y * y * drho + 6 * p1 * y + 2 * p2 * x
    return np.stack([np.stack([j00, j01], -1), np.stack([j01, j11], -1)], -2)


def distort_hessian(dist: Distortion, u: np.ndarray) -> np.ndarray:
    """(..., 2, 2, 2): [..., i, j, m] = d J_ij / d u_m of distort_jacobian."""
    x, y = u[..., 0], u[..., 1]
    _, d1, d2 = radial_profile(dist.kind, dist.k, x * x + y * y)
    p1, p2 = dist.p
    j00 = (6 * x * d1 + 4 * x ** 3 * d2 + 6 * p2, 2 * y * d1 + 4 * x * x * y * d2 + 2 * p1)
    j01 = (2 * y * d1 + 4 * x * x * y * d2 + 2 * p1, 2 * x * d1 + 4 * x * y * y * d2 + 2 * p2)
    j11 = (2 * x * d1 + 4 * x * y * y * d2 + 2 * p2, 6 * y * d1 + 4 * y ** 3 * d2 + 6 * p1)
    rows = [np.stack(j00, -1), np.stack(j01, -1), np.stack(j01, -1), np.stack(j11, -1)]
    return np.stack(rows, -2).reshape(u.shape[:-1] + (2, 2, 2))


def undistort(dist: Distortion, d: np.ndarray, start: np.ndarray, iterations: int = 50) -> np.ndarray:
    """(..., 2) undistorted points whose D is d, by Newton's method from `start` (at most `iterations` steps); NaN
    where it did not converge."""
    u = np.array(start, np.float64)
    for _ in range(iterations):
        step = np.linalg.solve(distort_jacobian(dist, u), (distort(dist, u) - d)[..., None])[..., 0]
        u = u - step
        if not np.abs(step).max(initial=0.0) > 1e-15:   # converged (or NaN: then the check below fails)
            break
    ok = np.linalg.norm(distort(dist, u) - d, axis=-1) <= 1e-9 * (1 + np.linalg.norm(d, axis=-1))
    return np.where(ok[..., None], u, np.nan)


def field_reach(kind: int, k) -> tuple[np.ndarray, np.ndarray, bool]:
    """The radial map up to where it stops growing (or MAX_FIELD_ANGLE): undistorted radii r, the distorted radii they
    reach (increasing), and whether it grows all the way to MAX_FIELD_ANGLE."""
    angle = np.linspace(0.0, MAX_FIELD_ANGLE, FIELD_SAMPLES)
    r = np.tan(angle)
    rho, drho, _ = radial_profile(kind, k, r * r)
    growing = (rho + 2 * r * r * drho > 0) & (r * rho >= 0)
    last = FIELD_SAMPLES if growing.all() else int(np.argmin(growing))
    return r[:last], (r * rho)[:last], bool(growing.all())


def undistort_points(dist: Distortion, d: np.ndarray) -> np.ndarray:
    """(..., 2) the undistorted points of distorted ones: Newton's method from the radial map's inverse (its table of
    field_reach); NaN where it does not converge."""
    r, reach, _ = field_reach(dist.kind, dist.k)
    rd = np.linalg.norm(d, axis=-1)
    start = d * (np.interp(rd, reach, r) / np.maximum(rd, 1e-300))[..., None]
    return undistort(dist, d, start)


def from_colmap(model: str, params, width: int, height: int, where, name: str
                ) -> tuple[tuple[float, float, float, float], Distortion | None]:
    """(fx, fy, cx, cy) and the Distortion (None: all its coefficients 0) of a COLMAP camera of a DIRECT_MODELS model,
    with its clamp box and culling radius; InputError naming `where` and the image if the model cannot be inverted
    over the image: its radial map stops growing before the image's corner, or the map folds (det dD/du <= 0)
    inside the image."""
    names, kind = DIRECT_MODELS[model]
    value = dict(zip(names, (float(v) for v in params)))
    fx, fy = value.get("fx", value.get("f")), value.get("fy", value.get("f"))
    intrinsics = (fx, fy, value["cx"], value["cy"])
    k = tuple(value.get(n, 0.0) for n in RADIAL_NAMES)
    p = (value.get("p1", 0.0), value.get("p2", 0.0))
    if not any(k) and not any(p):
        return intrinsics, None
    dist = Distortion(model, kind, k, p)
    coefficients = ", ".join(f"{n}={value[n]:g}" for n in names if n[0] in "kp")
    problem = f"image {name!r}: the {model} distortion ({coefficients}) cannot be rendered directly: "

    r, reach, grows = field_reach(kind, k)   # where the radial map d = r rho(r^2) stops growing
    # the image's border in distorted normalised coordinates, taken back to undistorted ones
    edge = np.linspace(0.0, 1.0, 65)
    px = np.concatenate([edge * width, np.full_like(edge, width), edge[::-1] * width, np.zeros_like(edge)])
    py = np.concatenate([np.zeros_like(edge), edge * height, np.full_like(edge, height), edge[::-1] * height])
    d = np.stack([(px - intrinsics[2]) / fx, (py - intrinsics[3]) / fy], -1)
    if len(r) < 2 or np.linalg.norm(d, axis=-1).max() >= reach[-1]:
        if grows:
            raise InputError(where, problem + f"the image's corner lies more than {np.degrees(MAX_FIELD_ANGLE):.0f} "
                                              "deg from the axis, past what a projection through x/z reaches")
        raise InputError(where, problem + f"its radial map turns back {np.degrees(np.arctan(r[-1])):.1f} deg from "
                                          "the axis, short of the image's corner")
    u = undistort_points(dist, d)
    if not np.isfinite(u).all():
        raise InputError(where, problem + "the image's border cannot be mapped back to the camera's rays")
    rays = u[None, :, :] * np.linspace(0.0, 1.0, 33)[:, None, None]
    if not (np.linalg.det(distort_jacobian(dist, rays)) > 0).all():
        raise InputError(where, problem + "the map folds over (det dD/du <= 0) inside the image")
    lim = FOV_CLAMP * np.abs(u).max(axis=0)
    r2_max = min(r[-1] ** 2, (FOV_CLAMP * np.linalg.norm(u, axis=-1).max()) ** 2)
    return intrinsics, Distortion(model, kind, k, p, (float(lim[0]), float(lim[1])), float(r2_max))

