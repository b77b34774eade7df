import numpy as np
import pytest

from dc4gs_cl.render.sort import RadixSort, digit_plan
from dc4gs_cl.render.stage import StageContext
from helpers import SHAPES


def test_digit_plan_covers_exactly_the_requested_bits():
    for lo, hi, radix in [(0, 32, 8), (0, 31, 8), (3, 17, 4), (0, 9, 8), (5, 5, 8), (0, 1, 8), (0, 23, 6)]:
        plan = digit_plan(lo, hi, radix)
        assert sum(b for _, b in plan) == hi - lo
        assert all(1 <= b <= radix for _, b in plan)
        assert len(plan) == -(-(hi - lo) // radix)
        assert [s for s, _ in plan] == [lo + sum(b for _, b in plan[:i]) for i in range(len(plan))]


@pytest.mark.parametrize("shape", SHAPES)
def test_radix_sort_is_a_stable_sort_of_the_requested_bits(rt, rng, shape):
    for n, lo, hi in [(1, 0, 32), (2, 0, 32), (1000, 0, 32), (int(rng.integers(10_000, 200_000)), 0, 32),
                      (50_000, 0, 11), (30_000, 4, 20), (777, 0, 1)]:
        sort = RadixSort(StageContext(rt, SHAPES[shape], poison=True))   # fresh poisoned scratch per case
        keys = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
        if n > 10:   # many duplicates, so that stability matters
            keys[rng.random(n) < 0.5] = keys[0]
        vals = np.arange(n, dtype=np.uint32)
        kb, vb = sort(rt.to_device(keys), rt.to_device(vals), n, lo, hi)
        got_k, got_v = rt.to_host(kb, n, np.uint32), rt.to_host(vb, n, np.uint32)
        sort_key = (keys >> np.uint32(lo)) & np.uint32((1 << (hi - lo)) - 1 if hi - lo < 32 else 0xFFFFFFFF)
        order = np.argsort(sort_key, kind="stable")
        np.testing.assert_array_equal(got_v, order, err_msg=f"n={n} bits=[{lo},{hi})")
        np.testing.assert_array_equal(got_k, keys[order])


def test_radix_sort_with_no_bits_or_one_key_returns_input(rt):
    sort = RadixSort(StageContext(rt, SHAPES["cpu"]))
    keys, vals = rt.to_device(np.array([5, 3], np.uint32)), rt.to_device(np.array([0, 1], np.uint32))
    assert sort(keys, vals, 2, 0, 0) == (keys, vals)
    assert sort(keys, vals, 1, 0, 32) == (keys, vals)
