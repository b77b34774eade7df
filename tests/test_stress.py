"""Numerical stress: degenerate Gaussians and images never put NaN or Inf into images, gradients or
parameters; and the emulated float atomic add is exact under contention."""
import numpy as np
import pytest

from dc4gs_cl.backward import ProjectBackward, RasterizeBackward, SumsLayout
from dc4gs_cl.host.adam import Adam
from dc4gs_cl.loss import Loss
from dc4gs_cl.model import group_widths
from dc4gs_cl.render import DeviceGaussians, Renderer
from dc4gs_cl.render.gaussians import DeviceArrays
from dc4gs_cl.render.workspace import POISON
from dc4gs_cl.scene.camera import Camera
from dc4gs_cl.testing import random_model

CASES = ["zero scales", "huge scales", "needles", "near plane", "behind camera", "coincident", "opacity +30",
         "opacity -30", "zero quaternions", "one-colour image", "all at once"]


def degenerate_model(rng, case, cam, n=600):
    model = random_model(rng, n, spread=0.8)
    pick = rng.permutation(n)[: n // 2] if case != "all at once" else np.arange(n)
    groups = np.array_split(pick, 9) if case == "all at once" else [pick] * 9
    forward = cam.R[2]
    edits = {
        "zero scales": lambda i: model.log_scales.__setitem__(i, -40.0),
        "huge scales": lambda i: model.log_scales.__setitem__(i, 15.0),
        "needles": lambda i: model.log_scales.__setitem__((i, 0), -30.0),
        "near plane": lambda i: model.means.__setitem__(i, cam.center + forward * rng.uniform(0.1, 0.3, (len(i), 1))),
        "behind camera": lambda i: model.means.__setitem__(i, cam.center - forward * rng.uniform(0.0, 1.0, (len(i), 1))),
        "coincident": lambda i: model.means.__setitem__(i, model.means[i[0]]),
        "opacity +30": lambda i: model.opacity_logits.__setitem__(i, 30.0),
        "opacity -30": lambda i: model.opacity_logits.__setitem__(i, -30.0),
        "zero quaternions": lambda i: model.quats.__setitem__(i, 0.0),
    }
    if case == "all at once":
        for (name, edit), idx in zip(edits.items(), groups):
            edit(idx)
    elif case in edits:
        edits[case](pick)
    return model


@pytest.mark.parametrize("case", CASES)
def test_degenerate_gaussians_stay_finite_through_a_training_step(rt, rng, case):
    cam = Camera.look_at("c", (0.0, -3.0, 0.5), (0.0, 0.0, 0.0), 96, 64, fov_x=1.0)
    model = degenerate_model(rng, case, cam)
    target = np.full((64, 96, 3), 0.37, np.float32) if case in ("one-colour image", "all at once") \
        else rng.uniform(0, 1, (64, 96, 3)).astype(np.float32)
    g = DeviceGaussians(rt, model)
    renderer = Renderer(rt, poison=True)
    widths = group_widths(g.sh_coeffs)
    grads = DeviceArrays(rt, widths, g.n)
    adam = Adam(rt, widths, g.n)
    loss = Loss(renderer.context)
    rasterize_backward, project_backward = RasterizeBackward(renderer.context), ProjectBackward(renderer.context)
    grad_image, target_buf = rt.buffer(target.nbytes), rt.to_device(target)
    layout = SumsLayout(stats=True, dc_stats=True)
    lrs = {"means": 1e-3, "log_scales": 5e-3, "quats": 1e-3, "opacity_logits": 0.05, "sh": (2.5e-3, 1.25e-4)}
    for _ in range(3):
        res = renderer.render(g, cam, 3, (0.2, 0.3, 0.4))
        image = res.image(rt)
        assert np.isfinite(image).all()
        for buf in list(grads.buffers.values()) + [grad_image]:
            rt.fill(buf, POISON, buf.size)    # every value the kernels below should write, poisoned first
        loss(res.raster.image, target_buf, cam.width, cam.height, grad_image)
        sums = rasterize_backward(res, grad_image, (0.2, 0.3, 0.4), layout)
        assert np.isfinite(rt.to_host(sums, (g.n, layout.width))).all()
        project_backward.gradients(g, cam, 3, res, sums, layout, grads.buffers)
        for name, values in grads.download().items():
            assert np.isfinite(values).all(), name
        project_backward.step(g, cam, 3, res, sums, layout, adam.step_value(lrs), adam.m, adam.v)   # as training does
        for name, values in g.download().items():
            assert np.isfinite(values).all(), name
    assert np.isfinite(loss.read_stats()["loss"])


ATOMIC_TEST = """
#include "common.h"
__kernel void hammer(__global float *totals, const uint slots, const uint reps) {
    uint i = get_global_id(0);
    for (uint r = 0; r < reps; ++r) atomic_add_float(totals + (i + r) % slots, (float)((i + r) % 7) + 0.5f);
}
__kernel void hammer_local(__global float *out, const uint reps) {
    __local float acc[2];
    uint lid = get_local_id(0);
    if (lid < 2) acc[lid] = 0.f;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint r = 0; r < reps; ++r) local_add_float(&acc[(lid + r) & 1], 1.0f);
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lid < 2) out[get_group_id(0) * 2 + lid] = acc[lid];
}
"""


def test_emulated_float_atomic_add_is_exact_under_contention(rt):
    """Many work-items hammer a few addresses with small half-integers (exact in float32 whatever the
    order), so any lost update shows up as a wrong total."""
    import pyopencl as cl
    from dc4gs_cl.runtime import kernel_source
    source = kernel_source("common.h") + ATOMIC_TEST.replace('#include "common.h"', "")
    prg = cl.Program(rt.context, source).build(options=rt.build_options())
    items, slots, reps = 1 << 14, 3, 64
    totals = rt.to_device(np.zeros(slots, np.float32))
    prg.hammer(rt.queue, (items,), (64,), totals, np.uint32(slots), np.uint32(reps))
    want = np.zeros(slots)
    i = np.arange(items)[:, None] + np.arange(reps)[None]
    np.add.at(want, (i % slots).ravel(), ((i % 7) + 0.5).ravel())
    np.testing.assert_array_equal(rt.to_host(totals, slots), want)
    groups, wg = 8, 64
    out = rt.buffer(4 * 2 * groups)
    prg.hammer_local(rt.queue, (groups * wg,), (wg,), out, np.uint32(reps))
    np.testing.assert_array_equal(rt.to_host(out, 2 * groups), wg * reps / 2)
