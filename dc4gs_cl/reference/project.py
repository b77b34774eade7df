"""Float64 reference of kernels/project.cl."""
from __future__ import annotations

import numpy as np

from .. import constants as K
from ..geometry import quat_to_rotmat
from ..scene.camera import Camera
from ..scene.distortion import distort, distort_hessian, distort_jacobian


def sh_basis(degree: int, d: np.ndarray) -> np.ndarray:
    """(N, 3) unit directions -> (N, (degree+1)^2) real SH basis values (the 3DGS convention)."""
    x, y, z = d.T
    cols = [np.full_like(x, K.SH_C0)]
    if degree > 0:
        cols += [-K.SH_C1 * y, K.SH_C1 * z, -K.SH_C1 * x]
    if degree > 1:
        c2 = K.SH_C2
        cols += [c2[0] * x * y, c2[1] * y * z, c2[2] * (2 * z * z - x * x - y * y), c2[3] * x * z,
                 c2[4] * (x * x - y * y)]
    if degree > 2:
        c3 = K.SH_C3
        xx, yy, zz = x * x, y * y, z * z
        cols += [c3[0] * y * (3 * xx - yy), c3[1] * x * y * z, c3[2] * y * (4 * zz - xx - yy),
                 c3[3] * z * (2 * zz - 3 * xx - 3 * yy), c3[4] * x * (4 * zz - xx - yy), c3[5] * z * (xx - yy),
                 c3[6] * x * (xx - 3 * yy)]
    return np.stack(cols, 1)


def tile_rect_reference(mean2d: np.ndarray, half_size: np.ndarray, tiles_x: int, tiles_y: int) -> np.ndarray:
    """(N, 4) int [x0, y0, x1, y1) of the tiles the box mean2d +- half_size (N, 2) px touches."""
    lo = np.floor((mean2d - half_size) / K.TILE_SIZE)
    hi = np.floor((mean2d + half_size) / K.TILE_SIZE) + 1
    grid = np.array([tiles_x, tiles_y])
    return np.concatenate([np.clip(lo, 0, grid), np.clip(hi, 0, grid)], 1).astype(np.int64)


def pair_rect_reference(mean2d, radius, alpha_extent, tiles_x: int, tiles_y: int) -> np.ndarray:
    """The tiles a Gaussian's pairs go to: the 3-sigma box cut down to the box where alpha can reach
    ALPHA_MIN (kernels/common.h, pair_rect)."""
    half = np.minimum(np.asarray(radius, np.float64)[:, None], alpha_extent)
    return tile_rect_reference(np.asarray(mean2d, np.float64), half, tiles_x, tiles_y)


def rect_area(rect: np.ndarray) -> np.ndarray:
    return np.maximum(rect[:, 2] - rect[:, 0], 0) * np.maximum(rect[:, 3] - rect[:, 1], 0)


def antialias_compensation(a, b, c):
    """The antialiased mode's opacity factor sqrt(det(Sigma) / det(Sigma + EWA_DILATION I)) from the dilated 2D
    covariance (a, b, c), and its square s (before the clamp at 0)."""
    eps = K.EWA_DILATION
    s = ((a - eps) * (c - eps) - b * b) / (a * c - b * b)
    return np.sqrt(np.maximum(s, 0.0)), s


def _clamp_limits(cam: Camera) -> tuple[float, float]:
    """|x/z|, |y/z| beyond which the Jacobian is taken at the limit: FOV_CLAMP x the half field (a pinhole's), the
    lens model's own box (distortion.Distortion.lim)."""
    if cam.distortion is not None:
        return cam.distortion.lim
    return K.FOV_CLAMP * 0.5 * cam.width / cam.fx, K.FOV_CLAMP * 0.5 * cam.height / cam.fy


def _jacobian(cam: Camera, tx, ty, z) -> np.ndarray:
    """(N, 2, 3) the projection's Jacobian at the clamped (tx, ty) = (x/z, y/z): a pinhole's, or the lens model's
    local one diag(f) dD/du d(x/z, y/z)/d(x, y, z)."""
    J = np.zeros((len(z), 2, 3))
    if cam.distortion is None:
        J[:, 0, 0], J[:, 0, 2] = cam.fx / z, -cam.fx * tx / z
        J[:, 1, 1], J[:, 1, 2] = cam.fy / z, -cam.fy * ty / z
        return J
    P = np.zeros((len(z), 2, 3))
    P[:, 0, 0], P[:, 0, 2], P[:, 1, 1], P[:, 1, 2] = 1 / z, -tx / z, 1 / z, -ty / z
    A = np.array([cam.fx, cam.fy])[:, None] * distort_jacobian(cam.distortion, np.stack([tx, ty], -1))
    return A @ P


def _pixels(cam: Camera, x, y, z) -> np.ndarray:
    """(N, 2) pixel positions of camera-space points (z > 0)."""
    if cam.distortion is None:
        return np.stack([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy], 1)
    d = distort(cam.distortion, np.stack([x / z, y / z], -1))
    return d * [cam.fx, cam.fy] + [cam.cx, cam.cy]


def project_reference(means, log_scales, quats, opacity_logits, sh, cam: Camera, sh_degree: int,
                      tiles_x: int, tiles_y: int, antialiased: bool = False) -> dict[str, np.ndarray]:
    """Per-Gaussian projection in float64; entries other than radius and tiles_touched are meaningful
    only where radius > 0. alpha_extent: half-sizes (px) of the box outside which alpha < ALPHA_MIN.
    antialiased: opacities times antialias_compensation."""
    means = np.asarray(means, np.float64)
    R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    pc = means @ R.T + t
    x, y, z = pc.T
    in_front = z > K.NEAR_PLANE
    zs = np.where(in_front, z, 1.0)
    if cam.distortion is not None:   # a centre past the lens model's invertible field is culled
        in_front &= (x / zs) ** 2 + (y / zs) ** 2 <= cam.distortion.r2_max

    M = quat_to_rotmat(quats) * np.exp(np.asarray(log_scales, np.float64))[:, None, :]
    sigma = M @ M.transpose(0, 2, 1)
    lim_x, lim_y = _clamp_limits(cam)
    tx, ty = np.clip(x / zs, -lim_x, lim_x), np.clip(y / zs, -lim_y, lim_y)
    T = _jacobian(cam, tx, ty, zs) @ R
    cov2d = T @ sigma @ T.transpose(0, 2, 1) + K.EWA_DILATION * np.eye(2)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det = a * c - b * b
    ok = in_front & (det > 0)
    dets = np.where(ok, det, 1.0)
    conic = np.stack([c / dets, -b / dets, a / dets], 1)
    mid = 0.5 * (a + c)
    lam = mid + np.sqrt(np.maximum(K.MIN_EIGEN_GAP, mid * mid - det))
    radius = np.where(ok, np.ceil(K.RADIUS_SIGMAS * np.sqrt(np.maximum(lam, 0))), 0)
    mean2d = _pixels(cam, x, y, zs)
    visible = ok & (radius > 0) & (rect_area(tile_rect_reference(mean2d, radius[:, None], tiles_x, tiles_y)) > 0)
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(opacity_logits, np.float64)))
    if antialiased:   # culled Gaussians' (a, b, c) replaced by a unit covariance: their values are never read
        comp, _ = antialias_compensation(np.where(ok, a, 1.0), np.where(ok, b, 0.0), np.where(ok, c, 1.0))
        opacity = opacity * np.where(ok, comp, 1.0)
    q = np.where(opacity >= K.ALPHA_MIN, 2 * np.log(np.maximum(opacity, K.ALPHA_MIN) / K.ALPHA_MIN), 0.0)
    alpha_extent = np.sqrt(q[:, None] * np.stack([a, c], 1).clip(0)) + K.ALPHA_EXTENT_MARGIN
    tiles = np.where(visible & (opacity >= K.ALPHA_MIN),
                     rect_area(pair_rect_reference(mean2d, radius, alpha_extent, tiles_x, tiles_y)), 0)

    d = means - cam.center
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    k = K.sh_coeffs(sh_degree)
    rgb = np.einsum("nk,nkc->nc", sh_basis(sh_degree, d), np.asarray(sh, np.float64)[:, :k]) + 0.5
    return {
        "mean2d": mean2d, "conic": conic, "opacity": opacity, "rgb": np.clip(rgb, 0.0, K.COLOR_MAX), "depth": z,
        "radius": np.where(visible, radius, 0).astype(np.int64), "alpha_extent": alpha_extent,
        "tiles_touched": tiles.astype(np.int64),
    }


def sh_basis_gradient(degree: int, d: np.ndarray) -> np.ndarray:
    """(N, 3) unit directions -> (N, (degree+1)^2, 3): d basis_k / d direction (direction not renormalised)."""
    x, y, z = d.T
    zero = np.zeros_like(x)
    rows = [(zero, zero, zero)]
    if degree > 0:
        c1 = K.SH_C1
        rows += [(zero, -c1 + zero, zero), (zero, zero, c1 + zero), (-c1 + zero, zero, zero)]
    if degree > 1:
        c2 = K.SH_C2
        rows += [(c2[0] * y, c2[0] * x, zero), (zero, c2[1] * z, c2[1] * y),
                 (-2 * c2[2] * x, -2 * c2[2] * y, 4 * c2[2] * z), (c2[3] * z, zero, c2[3] * x),
                 (2 * c2[4] * x, -2 * c2[4] * y, zero)]
    if degree > 2:
        c3 = K.SH_C3
        xx, yy, zz = x * x, y * y, z * z
        rows += [(6 * c3[0] * x * y, c3[0] * (3 * xx - 3 * yy), zero),
                 (c3[1] * y * z, c3[1] * x * z, c3[1] * x * y),
                 (-2 * c3[2] * x * y, c3[2] * (4 * zz - xx - 3 * yy), 8 * c3[2] * y * z),
                 (-6 * c3[3] * x * z, -6 * c3[3] * y * z, c3[3] * (6 * zz - 3 * xx - 3 * yy)),
                 (c3[4] * (4 * zz - 3 * xx - yy), -2 * c3[4] * x * y, 8 * c3[4] * x * z),
                 (2 * c3[5] * x * z, -2 * c3[5] * y * z, c3[5] * (xx - yy)),
                 (c3[6] * (3 * xx - 3 * yy), -6 * c3[6] * x * y, zero)]
    return np.stack([np.stack(r, -1) for r in rows], 1)


def project_backward_reference(means, log_scales, quats, opacity_logits, sh, cam: Camera, sh_degree: int,
                               v_mean2d, v_conic, v_opacity, v_rgb, visible, antialiased: bool = False,
                               regularizers: tuple[float, float] | None = None) -> dict[str, np.ndarray]:
    """Gradients of the parameters from the gradients of the projection's outputs (mean2d px, conic (a, b, c)
    as stored, opacity after the sigmoid (antialiased: times its compensation), rgb), in float64; zero where not
    visible but for the regularisers' (reg_opacity, reg_scale): d/d(logit, log scale) of reg_opacity sum(opacity)
    + reg_scale sum(scale), on every Gaussian. Through the EWA
    Jacobian (no gradient through a clamped x/z or y/z), the covariance, the rotation and scales, the SH
    colour (none where the colour clamps at 0 or COLOR_MAX) and its view direction."""
    means, sh = np.asarray(means, np.float64), np.asarray(sh, np.float64)
    R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    pc = means @ R.T + t
    x, y, z = pc.T
    z = np.where(visible, z, 1.0)
    q = np.asarray(quats, np.float64)
    qnorm = np.linalg.norm(q, axis=1)
    rotates = qnorm > K.QUAT_NORM_MIN
    qn = np.where(rotates[:, None], q / np.where(rotates, qnorm, 1)[:, None], [1.0, 0, 0, 0])
    Rq = quat_to_rotmat(qn)
    s = np.exp(np.asarray(log_scales, np.float64))
    M = Rq * s[:, None, :]
    sigma = M @ M.transpose(0, 2, 1)
    lim_x, lim_y = _clamp_limits(cam)
    ux, uy = x / z, y / z
    free_x, free_y = np.abs(ux) < lim_x, np.abs(uy) < lim_y
    tx, ty = np.clip(ux, -lim_x, lim_x), np.clip(uy, -lim_y, lim_y)
    T = _jacobian(cam, tx, ty, z) @ R
    cov = T @ sigma @ T.transpose(0, 2, 1) + K.EWA_DILATION * np.eye(2)
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det2 = (a * c - b * b) ** 2

    # conic = (c, -b, a) / det  ->  the covariance entries a, b, c
    vA, vB, vC = np.asarray(v_conic, np.float64).T
    da = (-vA * c * c + vB * b * c - vC * b * b) / det2
    db = (2 * vA * b * c - vB * (a * c + b * b) + 2 * vC * a * b) / det2
    dc = (-vA * b * b + vB * a * b - vC * a * a) / det2
    o = 1 / (1 + np.exp(-np.asarray(opacity_logits, np.float64)))
    v_opacity = np.asarray(v_opacity, np.float64)
    if antialiased:   # the opacity o x comp(a, b, c): the compensation's gradient to the covariance
        comp, square = antialias_compensation(a, b, c)
        det = a * c - b * b
        # d comp / d square, exact (the kernel adds gsplat's guard, + ANTIALIAS_GRAD_EPS, a relative 1e-6 / comp)
        v_square = v_opacity * o * np.where(comp > 0, 0.5 / np.where(comp > 0, comp, 1.0), 0.0)
        da = da + v_square * ((1 - square) * c / det - K.EWA_DILATION / det)
        db = db + v_square * 2 * (1 - square) * (-b) / det
        dc = dc + v_square * ((1 - square) * a / det - K.EWA_DILATION / det)
        v_opacity = v_opacity * comp
    Gm = np.stack([np.stack([da, 0.5 * db], -1), np.stack([0.5 * db, dc], -1)], 1)
    d_sigma = T.transpose(0, 2, 1) @ Gm @ T
    dJ = (2 * Gm @ T @ sigma) @ R.T

    # camera-space position: through J (unless clamped) and the projected mean
    vm = np.asarray(v_mean2d, np.float64)
    gradient = _pinhole_position_gradient if cam.distortion is None else _distorted_position_gradient
    dpc = gradient(cam, dJ, vm, x, y, z, tx, ty, free_x, free_y)
    d_means = dpc @ R

    # Sigma = M M^T, M = Rq diag(s)
    dM = 2 * d_sigma @ M
    d_log_scales = np.einsum("nij,nij->nj", dM, Rq) * s
    dR = dM * s[:, None, :]
    w, qx, qy, qz = qn.T
    dq = 2 * np.stack([
        -qz * dR[:, 0, 1] + qy * dR[:, 0, 2] + qz * dR[:, 1, 0] - qx * dR[:, 1, 2] - qy * dR[:, 2, 0]
        + qx * dR[:, 2, 1],
        qy * dR[:, 0, 1] + qz * dR[:, 0, 2] + qy * dR[:, 1, 0] - 2 * qx * dR[:, 1, 1] - w * dR[:, 1, 2]
        + qz * dR[:, 2, 0] + w * dR[:, 2, 1] - 2 * qx * dR[:, 2, 2],
        -2 * qy * dR[:, 0, 0] + qx * dR[:, 0, 1] + w * dR[:, 0, 2] + qx * dR[:, 1, 0] + qz * dR[:, 1, 2]
        - w * dR[:, 2, 0] + qz * dR[:, 2, 1] - 2 * qy * dR[:, 2, 2],
        -2 * qz * dR[:, 0, 0] - w * dR[:, 0, 1] + qx * dR[:, 0, 2] + w * dR[:, 1, 0] - 2 * qz * dR[:, 1, 1]
        + qy * dR[:, 1, 2] + qx * dR[:, 2, 0] + qy * dR[:, 2, 1]], 1)
    d_quats = np.where(rotates[:, None],
                       (dq - qn * np.sum(qn * dq, 1, keepdims=True)) / np.where(rotates, qnorm, 1)[:, None], 0.0)

    # SH colour along the view direction; no gradient where the colour clamps at 0
    v = means - cam.center
    vnorm = np.linalg.norm(v, axis=1)
    d = v / vnorm[:, None]
    k = K.sh_coeffs(sh_degree)
    basis = sh_basis(sh_degree, d)
    raw = np.einsum("nk,nkc->nc", basis, sh[:, :k]) + 0.5
    vr = np.where((raw > 0) & (raw < K.COLOR_MAX), np.asarray(v_rgb, np.float64), 0.0)
    d_sh = np.zeros_like(sh)
    d_sh[:, :k] = basis[:, :, None] * vr[:, None, :]
    d_dir = np.einsum("nkc,nc,nki->ni", sh[:, :k], vr, sh_basis_gradient(sh_degree, d))
    d_means += (d_dir - d * np.sum(d * d_dir, 1, keepdims=True)) / vnorm[:, None]

    out = {"means": d_means, "log_scales": d_log_scales, "quats": d_quats,
           "opacity_logits": v_opacity * o * (1 - o), "sh": d_sh}
    out = {key: np.where(np.reshape(visible, (-1,) + (1,) * (val.ndim - 1)), val, 0.0) for key, val in out.items()}
    if regularizers is not None:
        out["opacity_logits"] = out["opacity_logits"] + regularizers[0] * o * (1 - o)
        out["log_scales"] = out["log_scales"] + regularizers[1] * s
    return out


def _pinhole_position_gradient(cam, dJ, vm, x, y, z, tx, ty, free_x, free_y) -> np.ndarray:
    """(N, 3) dL/d(camera-space position) through a pinhole's Jacobian (dL/dJ: dJ) and projected mean (vm)."""
    n = len(z)
    dtx_dx, dtx_dz = np.where(free_x, 1 / z, 0), np.where(free_x, -x / z ** 2, 0)
    dty_dy, dty_dz = np.where(free_y, 1 / z, 0), np.where(free_y, -y / z ** 2, 0)
    dpc = np.zeros((n, 3))
    dpc[:, 0] = dJ[:, 0, 2] * (-cam.fx / z) * dtx_dx + vm[:, 0] * cam.fx / z
    dpc[:, 1] = dJ[:, 1, 2] * (-cam.fy / z) * dty_dy + vm[:, 1] * cam.fy / z
    dpc[:, 2] = (dJ[:, 0, 0] * (-cam.fx / z ** 2) + dJ[:, 0, 2] * (cam.fx * tx / z ** 2 - cam.fx / z * dtx_dz)
                 + dJ[:, 1, 1] * (-cam.fy / z ** 2) + dJ[:, 1, 2] * (cam.fy * ty / z ** 2 - cam.fy / z * dty_dz)
                 - (vm[:, 0] * cam.fx * x + vm[:, 1] * cam.fy * y) / z ** 2)
    return dpc


def _distorted_position_gradient(cam, dJ, vm, x, y, z, tx, ty, free_x, free_y) -> np.ndarray:
    """(N, 3) dL/d(camera-space position) through the lens model's local Jacobian J = A P (A = diag(f) dD/du at the
    clamped t, P = d(x/z, y/z)/d(x, y, z)) and the distorted mean f D(u) + c at the unclamped u."""
    dist, f = cam.distortion, np.array([cam.fx, cam.fy])
    t, u = np.stack([tx, ty], -1), np.stack([x / z, y / z], -1)
    A = f[:, None] * distort_jacobian(dist, t)
    dA = (dJ[:, :, :2] - dJ[:, :, 2:3] * t[:, None, :]) / z[:, None, None]
    dP = A.transpose(0, 2, 1) @ dJ                              # dL/dP[c][k]
    dz = (-(dP[:, 0, 0] + dP[:, 1, 1]) + dP[:, 0, 2] * tx + dP[:, 1, 2] * ty) / z ** 2
    dt = np.einsum("nrc,nrcm->nm", f[:, None] * dA, distort_hessian(dist, t)) - dP[:, :, 2] / z[:, None]
    dt = dt * np.stack([free_x, free_y], -1)
    du = dt + np.einsum("nr,nrc->nc", f * vm, distort_jacobian(dist, u))
    return np.stack([du[:, 0] / z, du[:, 1] / z, dz - (du[:, 0] * u[:, 0] + du[:, 1] * u[:, 1]) / z], 1)
