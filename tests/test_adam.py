"""Our Adam against a float64 NumPy transcription of PyTorch's update rule, and the schedule."""
import numpy as np

from dc4gs_cl.host.adam import Adam, AdamConfig, exponential_lr
from dc4gs_cl.render.gaussians import DeviceArrays


def adam_reference(p, g, m, v, t, lr, b1=0.9, b2=0.999, eps=1e-15):
    m = b1 * m + (1 - b1) * g
    v = b2 * v + (1 - b2) * g * g
    return p - (lr / (1 - b1 ** t)) * m / (np.sqrt(v / (1 - b2 ** t)) + eps), m, v


def test_adam_matches_reference_over_several_steps(rt, rng):
    widths = {"a": 3, "b": 1}
    n = 1000
    params = DeviceArrays(rt, widths, n)
    grads = DeviceArrays(rt, widths, n)
    host = {k: rng.normal(size=(n, w)) for k, w in widths.items()}
    params.upload(host)
    adam = Adam(rt, widths, n, AdamConfig())
    m = {k: np.zeros_like(x) for k, x in host.items()}
    v = {k: np.zeros_like(x) for k, x in host.items()}
    steps = {"a": 0, "b": 0}
    for it in range(5):
        g = {k: rng.normal(scale=10.0 ** rng.uniform(-8, 1), size=(n, w)) for k, w in widths.items()}
        grads.upload(g)
        # b skips some steps; a's first lane steps at another rate (as the SH DC band does)
        lrs = {"a": (1e-3 * (it + 1), 2e-4)} if it % 2 else {"a": (1e-3, 5e-5), "b": 0.05}
        adam.step(params, grads, lrs, split_lanes=1)
        for k, lr in lrs.items():
            steps[k] += 1
            rate = np.array([lr[0]] + [lr[1]] * (widths[k] - 1)) if isinstance(lr, tuple) else lr
            host[k], m[k], v[k] = adam_reference(host[k], g[k], m[k], v[k], steps[k], rate)
    got = params.download()
    for k in widths:
        np.testing.assert_allclose(got[k], host[k], rtol=1e-5, atol=1e-6)
    assert adam.steps == steps


def test_exponential_lr_schedule():
    assert np.isclose(exponential_lr(0, 1.6e-4, 1.6e-6, 30_000), 1.6e-4)
    assert np.isclose(exponential_lr(30_000, 1.6e-4, 1.6e-6, 30_000), 1.6e-6)
    assert np.isclose(exponential_lr(15_000, 1.6e-4, 1.6e-6, 30_000), 1.6e-5)
    assert np.isclose(exponential_lr(40_000, 1.6e-4, 1.6e-6, 30_000), 1.6e-6)
