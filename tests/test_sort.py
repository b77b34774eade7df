from dataclasses import replace

import numpy as np
import pytest

from dc4gs_cl.render.sort import RadixSort, digit_plan
from dc4gs_cl.render.stage import StageContext
from dc4gs_cl.render.workspace import POISON
from helpers import SHAPES


def test_digit_plan_covers_exactly_the_requested_bits():
    for lo, hi, radix in [(0, 32, 8), (0, 31, 8), (3, 17, 4), (0, 9, 8), (5, 5, 8), (0, 1, 8), (0, 23, 6)]:
        plan = digit_plan(lo, hi, radix)
        assert sum(b for _, b in plan) == hi - lo
        assert all(1 <= b <= radix for _, b in plan)
        assert len(plan) == -(-(hi - lo) // radix)
        assert [s for s, _ in plan] == [lo + sum(b for _, b in plan[:i]) for i in range(len(plan))]


# the GPU shape with runs of several tiles each (a run per work-group, at most 3 work-groups)
SORT_SHAPES = {**SHAPES, "gpu-long-runs": replace(SHAPES["gpu"], sort_blocks=3)}


@pytest.mark.parametrize("shape", SORT_SHAPES)
def test_radix_sort_is_a_stable_sort_of_the_requested_bits(rt, rng, shape):
    widths = [(lo, lo + width) for width in range(1, 33) for lo in [int(rng.integers(0, 33 - width))]]
    cases = [(1, 0, 32), (2, 0, 32), (1000, 0, 32), (int(rng.integers(10_000, 200_000)), 0, 32), (50_000, 0, 11),
             (30_000, 4, 20), (777, 0, 1), *[(int(rng.integers(1_500, 5_000)), lo, hi) for lo, hi in widths]]
    for n, lo, hi in cases:
        sort = RadixSort(StageContext(rt, SORT_SHAPES[shape], poison=True))   # fresh poisoned scratch per case
        keys = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
        if n > 10:   # many duplicates, so that stability matters, and the largest key (the ranked tiles' padding)
            keys[rng.random(n) < 0.5] = keys[0]
            keys[rng.random(n) < 0.1] = 0xFFFFFFFF
        vals = np.arange(n, dtype=np.uint32)
        kb, vb = sort(rt.to_device(keys), rt.to_device(vals), n, lo, hi)
        got_k, got_v = rt.to_host(kb, n, np.uint32), rt.to_host(vb, n, np.uint32)
        sort_key = (keys >> np.uint32(lo)) & np.uint32((1 << (hi - lo)) - 1 if hi - lo < 32 else 0xFFFFFFFF)
        order = np.argsort(sort_key, kind="stable")
        np.testing.assert_array_equal(got_v, order, err_msg=f"n={n} bits=[{lo},{hi})")
        np.testing.assert_array_equal(got_k, keys[order])


@pytest.mark.parametrize("shape", SORT_SHAPES)
def test_radix_sort_of_a_count_on_the_device_sorts_that_many_and_leaves_the_rest(rt, rng, shape):
    """The intersection's sorts take their key count from the device (no read-back): the launch is sized for the
    bound, the kernels sort the first count[count_at] keys, and nothing past them is read or written."""
    bound = 20_000
    for n in [0, 1, 2, 1023, 1024, 1025, int(rng.integers(3, bound)), bound]:
        sort = RadixSort(StageContext(rt, SORT_SHAPES[shape], poison=True))
        keys = rng.integers(0, 2**31, bound, dtype=np.uint64).astype(np.uint32)
        keys[rng.random(bound) < 0.5] = keys[0]
        count = rt.to_device(np.array([7, n, 9], np.uint32))
        keys_in = rt.to_device(keys)
        kb, vb = sort(keys_in, rt.to_device(np.arange(bound, dtype=np.uint32)), bound, 0, 31, count=count, count_at=1)
        got_k, got_v = rt.to_host(kb, bound, np.uint32), rt.to_host(vb, bound, np.uint32)
        order = np.argsort(keys[:n], kind="stable")
        np.testing.assert_array_equal(got_v[:n], order, err_msg=f"n={n}")
        np.testing.assert_array_equal(got_k[:n], keys[order])
        # past the count: the input as it was, or the scratch's poison, as the passes left the result
        np.testing.assert_array_equal(got_k[n:], keys[n:] if kb == keys_in else POISON, "the sort wrote past the count")


@pytest.mark.parametrize("shape", SORT_SHAPES)
def test_radix_sort_with_no_bits_or_at_most_one_key_returns_input(rt, shape):
    sort = RadixSort(StageContext(rt, SORT_SHAPES[shape]))
    keys, vals = rt.to_device(np.array([5, 3], np.uint32)), rt.to_device(np.array([0, 1], np.uint32))
    launches = rt.launches
    assert sort(keys, vals, 2, 0, 0) == (keys, vals)
    assert sort(keys, vals, 1, 0, 32) == (keys, vals)
    assert sort(keys, vals, 0, 0, 32) == (keys, vals)
    assert rt.launches == launches


@pytest.mark.parametrize("shape", SORT_SHAPES)
def test_radix_sort_takes_three_launches_per_digit(rt, rng, shape):
    sort = RadixSort(StageContext(rt, SORT_SHAPES[shape]))
    keys = rt.to_device(rng.integers(0, 2**32, 5000, dtype=np.uint64).astype(np.uint32))
    vals = rt.to_device(np.arange(5000, dtype=np.uint32))
    launches = rt.launches
    sort(keys, vals, 5000, 3, 30)
    assert rt.launches - launches == 3 * len(digit_plan(3, 30, SORT_SHAPES[shape].radix_bits))


def test_ranked_sort_narrows_its_work_groups_to_the_local_memory(rt, rng, monkeypatch):
    """A device with little local memory (here 12 KiB) runs the ranked shape in narrower work-groups, with the
    same result."""
    monkeypatch.setattr(rt, "caps", replace(rt.caps, local_mem_size=12 * 1024))
    sort = RadixSort(StageContext(rt, SORT_SHAPES["gpu"]))
    assert 1 < sort.wg < SORT_SHAPES["gpu"].sort_wg
    assert rt.kernel_limits(sort.k_scatter).local_bytes <= 12 * 1024
    keys = rng.integers(0, 64, 5000).astype(np.uint32)
    _, vb = sort(rt.to_device(keys), rt.to_device(np.arange(5000, dtype=np.uint32)), 5000, 0, 6)
    np.testing.assert_array_equal(rt.to_host(vb, 5000, np.uint32), np.argsort(keys, kind="stable"))
