"""Projection stage (kernels/project.cl): per-Gaussian 2D mean, conic, opacity, colour, depth, radius
and tile count for one camera."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..runtime import CAMERA_DTYPE, Runtime
from ..scene.camera import Camera
from .gaussians import DeviceGaussians
from .workspace import Workspace

PER_GAUSSIAN_WG = 64   # work-group size of the kernels with one work-item per Gaussian


def camera_struct(cam: Camera) -> np.void:
    c = np.zeros(1, CAMERA_DTYPE)
    c["R"] = np.asarray(cam.R, np.float64).reshape(9)
    c["t"] = cam.t
    c["fx"], c["fy"], c["cx"], c["cy"] = cam.fx, cam.fy, cam.cx, cam.cy
    c["campos"] = cam.center
    c["width"], c["height"] = cam.width, cam.height
    return c[0]


@dataclass
class Projected:
    """Per-Gaussian outputs of the projection (layouts in kernels/project.cl); values other than
    radius and tiles_touched are defined only where radius > 0."""
    n: int
    mean2d: cl.Buffer
    conic_opacity: cl.Buffer
    rgb: cl.Buffer
    depth: cl.Buffer
    radius: cl.Buffer
    alpha_extent: cl.Buffer
    tiles_touched: cl.Buffer


def project(rt: Runtime, ws: Workspace, g: DeviceGaussians, cam: Camera, sh_degree: int,
            tiles_x: int, tiles_y: int, defines: dict) -> Projected:
    n = g.n
    out = Projected(n=n, mean2d=ws.get("proj.mean2d", 8 * n), conic_opacity=ws.get("proj.conic_opacity", 16 * n),
                    rgb=ws.get("proj.rgb", 12 * n), depth=ws.get("proj.depth", 4 * n),
                    radius=ws.get("proj.radius", 4 * n), alpha_extent=ws.get("proj.alpha_extent", 8 * n),
                    tiles_touched=ws.get("proj.tiles_touched", 4 * n))
    if n == 0:
        return out
    k = rt.kernel("project.cl", "project", {**defines, "SH_COEFFS": g.sh_coeffs})
    b = g.buffers
    rt.launch_items("project", k, n, PER_GAUSSIAN_WG,
              np.int32(n), camera_struct(cam), np.int32(min(sh_degree, g.sh_degree)),
              np.int32(tiles_x), np.int32(tiles_y),
              b["means"], b["log_scales"], b["quats"], b["opacity_logits"], b["sh"],
              out.mean2d, out.conic_opacity, out.rgb, out.depth, out.radius, out.alpha_extent, out.tiles_touched)
    return out
