import numpy as np
import pytest

from dc4gs_cl.render.scan import ExclusiveScan
from dc4gs_cl.render.stage import StageContext
from dc4gs_cl.render.workspace import POISON
from helpers import SHAPES


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("flags", [False, True])
def test_exclusive_scan_matches_cumsum(rt, rng, shape, flags):
    scan = ExclusiveScan(StageContext(rt, SHAPES[shape]), flags=flags)
    for n in [1, 2, 7, 255, 256, 257, 1000, int(rng.integers(2_000, 300_000))]:
        values = rng.integers(0, 50, n).astype(np.uint32)
        values[rng.random(n) < 0.3] = 0
        src = rt.to_device(values)
        dst = rt.to_device(np.full(n, POISON, np.uint32))
        total = rt.to_device(np.full(4, POISON, np.uint32))
        scan(src, dst, n, total, 2)
        x = (values != 0).astype(np.uint64) if flags else values.astype(np.uint64)
        expect = np.concatenate([[0], np.cumsum(x)[:-1]])
        got = rt.to_host(dst, n, np.uint32)
        np.testing.assert_array_equal(got, expect, err_msg=f"n={n}")
        tot = rt.to_host(total, 4, np.uint32)
        assert tot[2] == x.sum() and tot[0] == POISON and tot[3] == POISON


def test_scan_in_place_and_empty(rt, rng):
    scan = ExclusiveScan(StageContext(rt, SHAPES["cpu"]))
    values = rng.integers(0, 1000, 5000).astype(np.uint32)
    buf = rt.to_device(values)
    total = rt.to_device(np.full(1, POISON, np.uint32))
    scan(buf, buf, len(values), total, 0)
    np.testing.assert_array_equal(rt.to_host(buf, len(values), np.uint32),
                                  np.concatenate([[0], np.cumsum(values)[:-1]]))
    scan(buf, buf, 0, total, 0)
    assert rt.to_host(total, 1, np.uint32)[0] == 0


@pytest.mark.parametrize("shape", SHAPES)
def test_exclusive_scan_of_a_count_on_the_device(rt, rng, shape):
    """The intersection scans the visible Gaussians' counts, as many as the device counted (no read-back): the
    launch is sized for the bound, nothing past the count is written, the total is that of the count's elements."""
    scan = ExclusiveScan(StageContext(rt, SHAPES[shape]))
    bound = 50_000
    for n in [0, 1, 255, 257, int(rng.integers(2, bound)), bound]:
        values = rng.integers(0, 50, bound).astype(np.uint32)
        dst = rt.to_device(np.full(bound, POISON, np.uint32))
        total = rt.to_device(np.array([n, POISON], np.uint32))
        scan(rt.to_device(values), dst, bound, total, 1, count=total, count_at=0)
        got = rt.to_host(dst, bound, np.uint32)
        np.testing.assert_array_equal(got[:n], np.concatenate([[0], np.cumsum(values[:n], dtype=np.uint64)[:-1]])[:n])
        assert (got[n:] == POISON).all()
        assert rt.to_host(total, 2, np.uint32).tolist() == [n, values[:n].sum()]


@pytest.mark.parametrize("shape", SHAPES)
def test_gathering_scan_scans_the_elements_in_the_order_given(rt, rng, shape):
    """gather=True: element i is in[order[i]] (the intersection scans the visible Gaussians' tile counts in depth
    order), over a count taken from the device; nothing past it written."""
    scan = ExclusiveScan(StageContext(rt, SHAPES[shape]), gather=True)
    n_all = 40_000
    for n in [0, 1, 257, int(rng.integers(2, n_all)), n_all]:
        values = rng.integers(0, 50, n_all).astype(np.uint32)
        order = rng.permutation(n_all).astype(np.uint32)
        dst = rt.to_device(np.full(n_all, POISON, np.uint32))
        total = rt.to_device(np.array([n, POISON], np.uint32))
        scan(rt.to_device(values), dst, n_all, total, 1, count=total, count_at=0, order=rt.to_device(order))
        gathered = values[order[:n]].astype(np.uint64)
        got = rt.to_host(dst, n_all, np.uint32)
        np.testing.assert_array_equal(got[:n], np.concatenate([[0], np.cumsum(gathered)[:-1]])[:n])
        assert (got[n:] == POISON).all() and rt.to_host(total, 2, np.uint32).tolist() == [n, gathered.sum()]
    with pytest.raises(ValueError):
        scan(rt.to_device(values), dst, n_all, total, 1)
