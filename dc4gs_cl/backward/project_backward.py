"""Projection backward stage (kernels/project_backward.cl): from this view's per-Gaussian sums to the
parameters' gradients (stored, or added to a batch's: optim/batch_gradients.py), or, in training one view at a time,
straight to Adam's step on the parameters (the gradients never stored; the step's record is records.ADAM_STEP,
filled by optim/adam.py)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..model import PARAM_GROUPS
from ..records import camera_value, distortion_define, param_group_defines
from ..render.gaussians import DeviceGaussians
from ..render.renderer import RenderResult
from ..render.stage import PER_GAUSSIAN_WG, Stage
from ..runtime import DeviceArrays
from ..scene.camera import Camera
from ..statistics import SumsLayout


class ProjectBackward(Stage):
    FILE, KERNELS = "project_backward.cl", ("project_backward",)

    def defines(self) -> dict:
        return {**param_group_defines(), "ANTIALIASED": int(self.ctx.options.antialiased)}

    def gradients(self, g: DeviceGaussians, cam: Camera, sh_degree: int, res: RenderResult, sums: cl.Buffer,
                  layout: SumsLayout, grads: dict[str, cl.Buffer], regularizers: tuple[float, float] | None = None,
                  accumulate: bool = False) -> None:
        """The parameters' gradients into grads (buffers shaped like the parameters; zero for Gaussians not
        visible in the view but for the regularisers': (opacity_reg / N, scale_reg / 3N), MCMC's); accumulate:
        added to what grads hold."""
        self._launch(g, cam, sh_degree, res, sums, layout, False, [grads[name] for name in PARAM_GROUPS],
                     regularizers, accumulate)
        self.check(lambda: {f"d_{name}": self.rt.to_host(grads[name], (g.n, g.widths[name])) for name in PARAM_GROUPS})

    def step(self, g: DeviceGaussians, cam: Camera, sh_degree: int, res: RenderResult, sums: cl.Buffer,
             layout: SumsLayout, adam_step: np.void, m: DeviceArrays, v: DeviceArrays,
             regularizers: tuple[float, float] | None = None) -> None:
        """Adam's step on the parameters in place, each gradient stepping its parameter where it is computed
        (adam_step: a records.ADAM_STEP value; m, v: the moments, shaped like the parameters; regularizers: as
        gradients takes them)."""
        moments = [a.buffers[name] for name in PARAM_GROUPS for a in (m, v)]
        self._launch(g, cam, sh_degree, res, sums, layout, True, [adam_step] + moments, regularizers)
        self.check(lambda: {**g.download(), **{f"m_{k}": a for k, a in m.download().items()},
                            **{f"v_{k}": a for k, a in v.download().items()}})

    def _launch(self, g, cam, sh_degree, res, sums, layout, fused: bool, outputs: list, regularizers,
                accumulate: bool = False) -> None:
        n = g.n
        if n == 0:
            return
        k = self.kernels({"SH_COEFFS": g.sh_coeffs, "FUSED_ADAM": int(fused), "ACCUMULATE": int(accumulate),
                          "REGULARIZED": int(regularizers is not None), **layout.defines(),
                          **distortion_define(cam)})["project_backward"]
        reg = [np.float32(r) for r in regularizers] if regularizers is not None else []
        self.rt.launch_items("project_backward", k, n, PER_GAUSSIAN_WG, self.ctx.frame, np.int32(n), camera_value(cam),
                             np.int32(min(sh_degree, g.sh_degree)), *g.ordered(), res.proj.radius, sums, *reg,
                             *outputs)
