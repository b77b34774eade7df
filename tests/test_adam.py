"""Our Adam, fused into the projection's backward, against a float64 NumPy transcription of PyTorch's update
rule fed with the same kernel's stored gradients; and the learning-rate schedule."""
import numpy as np
import pytest
from helpers import random_model

from dc4gs_cl.backward import ProjectBackward
from dc4gs_cl.model import group_widths
from dc4gs_cl.optim.adam import Adam, AdamConfig, delayed_lr, exponential_lr
from dc4gs_cl.optim.batch_gradients import BatchGradients, batch_adam_config
from dc4gs_cl.render import DeviceGaussians, Renderer
from dc4gs_cl.runtime import DeviceArrays
from dc4gs_cl.scene.camera import Camera
from dc4gs_cl.statistics import GRADIENTS


def adam_reference(p, g, m, v, t, lr, b1=0.9, b2=0.999, eps=1e-15):
    m = b1 * m + (1 - b1) * g
    v = b2 * v + (1 - b2) * g * g
    return p - (lr / (1 - b1 ** t)) * m / (np.sqrt(v / (1 - b2 ** t)) + eps), m, v


def rel_l2(got, ref):
    assert np.isfinite(got).all()
    return np.linalg.norm(got - ref) / np.linalg.norm(ref)


@pytest.mark.parametrize("sh_degree", [0, 2, 3])   # SH rows of 3, 27, 48 floats: whole and partial float4s
def test_fused_adam_matches_reference_over_several_steps(rt, rng, sh_degree):
    cam = Camera.look_at("c", (0.3, -3.0, 0.8), (0.0, 0.0, 0.0), 64, 48, fov_x=0.9)
    model = random_model(rng, 800, sh_degree=sh_degree, spread=0.6, scale_range=(0.05, 0.3))
    model.means[-60:] = cam.center - cam.R[2] * rng.uniform(0.5, 2, (60, 1))   # behind: zero gradient, still steps
    g = DeviceGaussians(rt, model)
    n, widths = g.n, group_widths(g.sh_coeffs)
    renderer, layout = Renderer(rt), GRADIENTS
    backward = ProjectBackward(renderer.context)
    adam, grads = Adam(rt, widths, n, AdamConfig()), DeviceArrays(rt, widths, n)
    host = {k: v.astype(np.float64) for k, v in g.download().items()}
    m = {k: np.zeros_like(x) for k, x in host.items()}
    v = {k: np.zeros_like(x) for k, x in host.items()}
    steps = dict.fromkeys(widths, 0)
    for it in range(4):
        res = renderer.render(g, cam, 3)
        assert 0 < (rt.to_host(res.proj.radius, n, np.int32) > 0).sum() < n
        sums = rt.to_device(rng.normal(scale=10.0 ** rng.uniform(-6, 0), size=(n, layout.width)).astype(np.float32))
        backward.gradients(g, cam, 3, res, sums, layout, grads.buffers)
        grad = {k: x.astype(np.float64) for k, x in grads.download().items()}
        lrs = {"means": 1e-3 * (it + 1), "log_scales": 5e-3, "quats": 1e-3, "opacity_logits": 0.05,
               "sh": (2.5e-3, 1.25e-4)}
        if it % 2:
            del lrs["opacity_logits"]          # as on an opacity reset: that group does not step
        backward.step(g, cam, 3, res, sums, layout, adam.step_value(lrs), adam.m, adam.v)
        for k, lr in lrs.items():
            steps[k] += 1
            rate = np.repeat([lr[0], lr[1]], [3, widths[k] - 3]) if k == "sh" else lr
            host[k], m[k], v[k] = adam_reference(host[k], grad[k], m[k], v[k], steps[k], rate)
    got, got_m, got_v = g.download(), adam.m.download(), adam.v.download()
    start = {k: x.reshape(n, -1) for k, x in
             {"means": model.means, "log_scales": model.log_scales, "quats": model.quats,
              "opacity_logits": model.opacity_logits, "sh": model.sh}.items()}
    for k in widths:
        assert rel_l2(got[k] - start[k], host[k] - start[k]) < 1e-4, k     # the updates, not the values
        assert rel_l2(got_m[k], m[k]) < 1e-4, k
        assert rel_l2(got_v[k], v[k]) < 1e-4, k
    assert adam.steps == steps


@pytest.mark.parametrize("sh_degree,regularized", [(0, False), (3, True)])
def test_a_batch_sums_its_views_and_steps_on_their_mean(rt, rng, sh_degree, regularized):
    """--batch: each view's gradients added to the batch's in launch order (the float32 sums the host computes from
    the views' stored gradients, bit for bit), then one Adam step on their mean with the batch's betas (and MCMC's
    regularisers once), against the float64 reference."""
    cams = [Camera.look_at(f"c{k}", tuple(rng.uniform(-1, 1, 3) + (0, -3.0, 0.5)), (0.0, 0.0, 0.0), 64, 48, fov_x=0.9)
            for k in range(3)]
    model = random_model(rng, 700, sh_degree=sh_degree, spread=0.6, scale_range=(0.05, 0.3))
    g = DeviceGaussians(rt, model)
    n, widths = g.n, group_widths(g.sh_coeffs)
    renderer, layout = Renderer(rt), GRADIENTS
    backward, batch = ProjectBackward(renderer.context), BatchGradients(renderer.context, widths)
    config = batch_adam_config(len(cams))
    adam, single = Adam(rt, widths, n, config), DeviceArrays(rt, widths, n)
    # moments from earlier steps, v of m's size squared: updates of about the rates (float32 parameters resolve them)
    m_start = {k: rng.normal(scale=1e-3, size=(n, w)).astype(np.float32) for k, w in widths.items()}
    adam.m.upload(m_start)
    adam.v.upload({k: (x * x * rng.uniform(0.5, 2, x.shape)).astype(np.float32) for k, x in m_start.items()})
    m0, v0 = adam.m.download(), adam.v.download()
    host = {k: x.astype(np.float64) for k, x in g.download().items()}
    expected = {k: np.zeros((n, w), np.float32) for k, w in widths.items()}
    summed = batch.start(n)
    for cam in cams:
        res = renderer.render(g, cam, 3)
        sums = rt.to_device(rng.normal(scale=10.0 ** rng.uniform(-4, 0), size=(n, layout.width)).astype(np.float32))
        backward.gradients(g, cam, 3, res, sums, layout, single.buffers)
        for k, x in single.download().items():
            expected[k] = expected[k] + x
        backward.gradients(g, cam, 3, res, sums, layout, summed, accumulate=True)
    got_sums = batch.sums.download()
    for k in widths:
        np.testing.assert_array_equal(got_sums[k], expected[k], err_msg=k)
    regularizers = (0.01 / n, 0.02 / (3 * n)) if regularized else None
    # rates whose steps float32 parameters of size ~1 resolve to 1e-5 (the moments' test is the arithmetic)
    lrs = {"means": 1e-2, "log_scales": 5e-2, "quats": 1e-2, "opacity_logits": 0.05, "sh": (2.5e-2, 1e-2)}
    batch.step(g, len(cams), adam.step_value(lrs), adam.m, adam.v, regularizers)
    got, got_m, got_v = g.download(), adam.m.download(), adam.v.download()
    grad = {k: x.astype(np.float64) / len(cams) for k, x in expected.items()}
    if regularized:
        o = 1 / (1 + np.exp(-host["opacity_logits"]))
        grad["opacity_logits"] += regularizers[0] * o * (1 - o)
        grad["log_scales"] += regularizers[1] * np.exp(host["log_scales"])
    for k, lr in lrs.items():
        rate = np.repeat([lr[0], lr[1]], [3, widths[k] - 3]) if k == "sh" else lr
        want, m, v = adam_reference(host[k], grad[k], m0[k].astype(np.float64), v0[k].astype(np.float64), 1, rate,
                                    config.beta1, config.beta2)
        assert rel_l2(got[k] - host[k], want - host[k]) < 1e-4, k
        assert rel_l2(got_m[k], m) < 1e-4 and rel_l2(got_v[k], v) < 1e-4, k


def test_exponential_lr_schedule():
    assert np.isclose(exponential_lr(0, 1.6e-4, 1.6e-6, 30_000), 1.6e-4)
    assert np.isclose(exponential_lr(30_000, 1.6e-4, 1.6e-6, 30_000), 1.6e-6)
    assert np.isclose(exponential_lr(15_000, 1.6e-4, 1.6e-6, 30_000), 1.6e-5)
    assert np.isclose(exponential_lr(40_000, 1.6e-4, 1.6e-6, 30_000), 1.6e-6)


def test_delayed_lr_and_the_exposure_schedule():
    """The Inria code's delay: delay_mult at step 0, a quarter sine up to 1 at delay_steps, 1 after and without one;
    --exposure's rate is the log-linear schedule times it over the first EXPOSURE_DELAY of the run."""
    from dc4gs_cl.config import TrainConfig
    from dc4gs_cl.train.schedule import EXPOSURE_DELAY, EXPOSURE_DELAY_MULT, Schedule
    assert delayed_lr(0, 100, 0.01) == 0.01 and delayed_lr(100, 100, 0.01) == 1.0 and delayed_lr(250, 100, 0.01) == 1.0
    assert np.isclose(delayed_lr(50, 100, 0.01), 0.01 + 0.99 * np.sqrt(0.5)) and delayed_lr(0, 0, 0.01) == 1.0
    cfg = TrainConfig(scene="builtin", iterations=2000, exposure=True)
    schedule, delay = Schedule(cfg), round(EXPOSURE_DELAY * 2000)
    assert np.isclose(schedule.exposure_lr(0), cfg.lr_exposure * EXPOSURE_DELAY_MULT)
    for it in (delay // 3, delay, 1500):
        assert np.isclose(schedule.exposure_lr(it), exponential_lr(it, cfg.lr_exposure, cfg.lr_exposure_final, 2000) *
                          delayed_lr(it, delay, EXPOSURE_DELAY_MULT))
    assert schedule.exposure_lr(delay // 3) < 0.9 * exponential_lr(delay // 3, cfg.lr_exposure, cfg.lr_exposure_final,
                                                                   2000)
