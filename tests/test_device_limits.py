"""Device limits: every launch of a whole training step fits a small device (32-item work-groups, 8 KiB of local
memory, the kernels' own work-group limit at 32), and the step computes what it computes on this device's own
shape. Runtime.launch refuses a work-group beyond a kernel's limits, so a stage that chose a shape outside them
fails here by name."""
from dataclasses import replace

import numpy as np
import pyopencl as cl
import pytest

from dc4gs_cl.apps.bench import frozen_trainer
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.densify import DC4GSConfig
from dc4gs_cl.errors import DeviceError
from dc4gs_cl.runtime import Capabilities, Runtime
from dc4gs_cl.scene.builtin import builtin_scene
from dc4gs_cl.train import Trainer

SMALL = Capabilities(is_cpu=False, compute_units=1, max_work_group_size=32, local_mem_size=8 * 1024,
                     float_atomic_add=False, fp64=False)
STEPS = 6
CONFIGS = {"3dgs": {"strategy": "3dgs"},
           "absgs+DC4GS": {"strategy": "absgs", "dc4gs": DC4GSConfig(dcc=True, dcs=True)},
           "pixelgs+DC4GS --low-memory": {"strategy": "pixelgs", "dc4gs": DC4GSConfig(dcc=True, dcs=True),
                                          "low_memory": True}}


@pytest.fixture(scope="module")
def scene_and_state():
    """The built-in scene at 48x36 and a model trained 60 iterations on it (this device, its own shape)."""
    scene = builtin_scene(resolution=4)
    warm = Trainer(TrainConfig(scene="builtin", iterations=600), scene, Runtime())
    for _ in range(60):
        warm.step()
    return scene, warm.model.download()


def steps(rt: Runtime, scene, state, settings: dict) -> tuple[dict, dict]:
    """STEPS statistics-gathering steps (no densification) from `state`: the parameters and window statistics."""
    trainer = frozen_trainer(TrainConfig(scene="builtin", iterations=600, **settings), scene, rt, state, 100)
    for _ in range(STEPS):
        trainer.step()
    return trainer.model.download().params, trainer.strategy.window.download()


@pytest.mark.parametrize("config", CONFIGS)
def test_a_training_step_fits_a_small_device_and_matches_the_full_shape(scene_and_state, config):
    scene, state = scene_and_state
    small = Runtime()
    small.caps = SMALL                           # the limits every stage reads (shapes, fitting, launches)
    launches = []
    launch = small.launch

    def recorded(stage, kernel, global_size, local_size, *args):
        launches.append((stage, kernel.function_name, local_size, small.kernel_limits(kernel).local_bytes))
        return launch(stage, kernel, global_size, local_size, *args)

    small.launch = recorded
    got_params, got_stats = steps(small, scene, state, CONFIGS[config])
    want_params, want_stats = steps(Runtime(), scene, state, CONFIGS[config])

    sized = [(s, k, group) for s, k, group, _ in launches if group is not None]
    assert {k for _, k, _ in sized} >= {"project", "rasterize", "loss_ssim", "rasterize_backward", "project_backward"}
    assert all(int(np.prod(group)) <= SMALL.max_work_group_size for _, _, group in sized), sized
    assert all(local <= SMALL.local_mem_size for *_, local in launches)
    for key, want in want_params.items():
        got = got_params[key]
        assert np.isfinite(got).all(), key
        err = np.linalg.norm(got - want) / np.linalg.norm(want)
        assert err < 1e-5, (key, err)           # other shapes sum in other orders: float32 rounding only
    for key, want in want_stats.items():        # the densification window's statistics
        got = got_stats[key]
        assert np.isfinite(got).all(), key
        err = np.linalg.norm(got - want) / max(np.linalg.norm(want), 1e-30)
        assert err < 1e-3, (key, err)           # rare blend-threshold flips move whole pixels' statistics


def test_a_launch_beyond_a_kernels_limits_is_refused_by_name(rt):
    program = cl.Program(rt.context, "__kernel void add_one(__global float *a) { a[get_global_id(0)] += 1.f; }").build()
    kernel = cl.Kernel(program, "add_one")
    buf = rt.to_device(np.zeros(64, np.float32))
    limit = rt.kernel_limits(kernel).work_group
    with pytest.raises(DeviceError,
                       match=rf"stage test: kernel add_one .* work-groups of {2 * limit} items.*allows {limit}"):
        rt.launch("test", kernel, 2 * limit, 2 * limit, buf)
    narrow = Runtime()
    narrow.caps = replace(narrow.caps, max_work_group_size=8)
    kernel = cl.Kernel(cl.Program(narrow.context, "__kernel void add_one(__global float *a) "
                                                  "{ if (get_global_id(0) < 60) a[get_global_id(0)] += 1.f; }").build(),
                       "add_one")
    buf = narrow.to_device(np.zeros(64, np.float32))
    narrow.launch_items("test", kernel, 60, 64, buf)   # asks 64 per group, gets the limit of 8
    np.testing.assert_array_equal(narrow.to_host(buf, 64), np.r_[np.ones(60), np.zeros(4)])


def test_growing_per_gaussian_arrays_are_never_held_twice(rt):
    """The parameters' and Adam's arrays grow at a densification step (their contents are uploaded after), one
    old buffer released before its larger one is made: the peak is the old arrays but one, and the new one
    (holding both sets was the peak of a training run: 1,596 bytes per Gaussian with DC4GS, now 1,404)."""
    import gc

    from dc4gs_cl.runtime import DeviceArrays
    arrays = DeviceArrays(rt, {"a": 3, "b": 48, "c": 1}, 10_000)
    old = {k: b.size for k, b in arrays.buffers.items()}
    gc.collect()
    rt.reset_memory_peak()
    before = rt.memory_in_use
    arrays.resize(30_000)
    new = {k: b.size for k, b in arrays.buffers.items()}
    assert all(new[k] >= 4 * w * 30_000 for k, w in arrays.widths.items())
    held, peak = before, before
    for k in arrays.widths:          # one array at a time: its old buffer released, then its new one made
        held += new[k] - old[k]
        peak = max(peak, held)
    assert rt.memory_in_use == held and rt.memory_peak == peak


def test_growth_leaves_little_headroom_and_meets_a_jump_exactly():
    """A buffer that grows a little gets an eighth more than it needs (not half more than it had: headroom is
    peak memory, 160 bytes a pair in DC4GS' per-pair slots); a jump, and a first allocation, get what they ask."""
    from dc4gs_cl.runtime import BUFFER_GROWTH, BUFFER_HEADROOM, grown_size
    assert grown_size(1_000, 0) == 1_000
    assert grown_size(1_010, 1_000) == int(1_010 * (1 + BUFFER_HEADROOM)) < 1_500
    assert grown_size(1_400, 1_000) == int(1_000 * BUFFER_GROWTH)   # never more than 1.5 x what it had
    assert grown_size(4_000, 1_000) == 4_000                   # a jump: exactly what it asks
    rng = np.random.default_rng()
    for have, want in rng.integers(1, 10**9, (1000, 2)):
        if want > have:
            assert want <= grown_size(int(want), int(have)) <= max(want, min((1 + BUFFER_HEADROOM) * want,
                                                                             BUFFER_GROWTH * have))


def test_a_growing_scratch_buffer_is_never_held_twice(rt):
    """Growing keeps no contents, so the old buffer is released before the larger one is made: the peak
    is the larger one alone (holding both was the peak of a DC4GS training step)."""
    import gc

    from dc4gs_cl.render.workspace import Workspace
    ws = Workspace(rt, poison=True)
    small = ws.get("slots", 40_000).size
    gc.collect()
    rt.reset_memory_peak()
    before = rt.memory_in_use
    grown = ws.get("slots", 100_000)
    assert grown.size >= 100_000 and ws.get("slots", 90_000) is grown      # kept while it is large enough
    assert rt.memory_in_use == before - small + grown.size
    assert rt.memory_peak == rt.memory_in_use
