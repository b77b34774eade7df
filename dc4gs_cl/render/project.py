"""Projection stage (kernels/project.cl): per-Gaussian 2D mean, conic, opacity, colour, depth, radius
and tile count for one camera."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..records import camera_value, distortion_define
from ..scene.camera import Camera
from .gaussians import DeviceGaussians
from .stage import PER_GAUSSIAN_WG, Stage, visible_rows


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


class Project(Stage):
    FILE, KERNELS = "project.cl", ("project",)

    def defines(self) -> dict:
        return self.ctx.options.defines()

    def __call__(self, g: DeviceGaussians, cam: Camera, sh_degree: int, tiles_x: int, tiles_y: int) -> Projected:
        n, ws = g.n, self.ws
        out = Projected(n=n, mean2d=ws.get("proj.mean2d", 8 * n), conic_opacity=ws.get("proj.conic_opacity", 16 * n),
                        rgb=ws.get("proj.rgb", 12 * n), depth=ws.get("proj.depth", 4 * n),
                        radius=ws.get("proj.radius", 4 * n), alpha_extent=ws.get("proj.alpha_extent", 8 * n),
                        tiles_touched=ws.get("proj.tiles_touched", 4 * n))
        if n == 0:
            return out
        k = self.kernels({"SH_COEFFS": g.sh_coeffs, **distortion_define(cam)})["project"]
        self.rt.launch_items("project", k, n, PER_GAUSSIAN_WG,
                             np.int32(n), camera_value(cam), np.int32(min(sh_degree, g.sh_degree)),
                             np.int32(tiles_x), np.int32(tiles_y), *g.ordered(),
                             out.mean2d, out.conic_opacity, out.rgb, out.depth, out.radius, out.alpha_extent,
                             out.tiles_touched)
        self.check(lambda: self.outputs(out))
        return out

    def outputs(self, out: Projected) -> dict[str, np.ndarray]:
        """The visible Gaussians' outputs, on the host."""
        radius = self.rt.to_host(out.radius, out.n, np.int32)
        return {name: visible_rows(self.rt, getattr(out, name), radius, width)
                for name, width in (("mean2d", 2), ("conic_opacity", 4), ("rgb", 3), ("depth", 1), ("alpha_extent", 2))}
