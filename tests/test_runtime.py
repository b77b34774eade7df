"""Runtime.launch: a kernel's arguments are set again only where they changed, and the kernel always runs on the
arguments given."""
import gc

import numpy as np
import pyopencl as cl
import pytest

from dc4gs_cl.errors import DeviceError

SOURCE = """
__kernel void shifted(__global float *out, uint n, float shift, __global const float *values) {
    uint i = get_global_id(0);
    if (i < n) out[i] = values[i] + shift;
}
"""
N = 100


def test_a_launch_sets_only_the_arguments_that_changed_and_runs_on_those_given(rt, rng):
    kernel = cl.Kernel(cl.Program(rt.context, SOURCE).build(), "shifted")

    def run(out, shift, values) -> tuple[np.ndarray, int]:
        cl.enqueue_fill_buffer(rt.queue, out, np.float32(np.nan), 0, 4 * N)   # poisoned: the kernel writes it all
        before = rt.arguments_set
        rt.launch_items("test", kernel, N, 64, out, np.uint32(N), np.float32(shift), values)
        result = np.empty(N, np.float32)
        cl.enqueue_copy(rt.queue, result, out)
        return result, rt.arguments_set - before

    a, b = (rng.standard_normal(N).astype(np.float32) for _ in range(2))
    out_a, out_b, values_a = rt.buffer(4 * N), rt.buffer(4 * N), rt.to_device(a)

    result, set_now = run(out_a, 0.5, values_a)
    np.testing.assert_array_equal(result, a + np.float32(0.5))
    assert set_now == 4
    result, set_now = run(out_a, 0.5, values_a)                # the same values, new scalar objects
    np.testing.assert_array_equal(result, a + np.float32(0.5))
    assert set_now == 0
    result, set_now = run(out_b, -2.0, values_a)               # another output and shift
    np.testing.assert_array_equal(result, a - np.float32(2.0))
    assert set_now == 2
    result, set_now = run(out_b, -0.0, values_a)               # a shift equal as a number, other bits
    assert set_now == 1
    del values_a
    gc.collect()
    values_b = rt.to_device(b)                                 # may take the released buffer's handle
    result, set_now = run(out_b, -0.0, values_b)
    np.testing.assert_array_equal(result, b)
    assert set_now == 1


def test_a_launch_with_the_wrong_number_of_arguments_is_refused_by_name(rt):
    kernel = cl.Kernel(cl.Program(rt.context, SOURCE).build(), "shifted")
    with pytest.raises(DeviceError, match="kernel shifted takes 4 arguments, given 3"):
        rt.launch_items("test", kernel, N, 64, rt.buffer(4 * N), np.uint32(N), np.float32(0))
