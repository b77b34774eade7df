"""Initialisation: exact kNN scales against brute force, from_points, random_points."""
import numpy as np
import pytest

from dc4gs_cl.constants import SH_C0
from dc4gs_cl.model import (INIT_OPACITY, KNN_MIN_MEAN_SQ_DIST, from_points, knn_mean_sq_dist, logit,
                            random_points)


def brute_knn(points, k=3, queries=None):
    """Float64 reference: mean of the k smallest squared distances to the other points."""
    p = np.asarray(points, dtype=np.float64)
    queries = np.arange(len(p)) if queries is None else queries
    k = min(k, len(p) - 1)
    out = np.empty(len(queries))
    for s in range(0, len(queries), 128):
        q = queries[s:s + 128]
        d = ((p[q, None, :] - p[None, :, :]) ** 2).sum(axis=-1)
        d[np.arange(len(q)), q] = np.inf  # not the point itself; its duplicates stay at 0
        out[s:s + 128] = np.sort(np.partition(d, k - 1, axis=1)[:, :k], axis=1).mean(axis=1)
    return out


def clustered(rng, n):
    """SfM-like: tight clusters of very different sizes, points on a thin plane, sparse outliers."""
    parts = [rng.normal(rng.uniform(-5, 5, 3), 10.0 ** rng.uniform(-3, -0.5), (n // 20, 3))
             for _ in range(10)]
    plane = np.c_[rng.standard_cauchy((n // 4, 2)) * 0.3, rng.normal(0, 1e-3, n // 4)]
    return np.concatenate(parts + [plane, rng.uniform(-50, 50, (n - 10 * (n // 20) - n // 4, 3))])


CLOUDS = {
    "uniform": lambda rng: rng.random((3000, 3)),
    "clustered": lambda rng: clustered(rng, 4000),
    "duplicates": lambda rng: np.repeat(rng.random((1500, 3)), rng.integers(1, 5, 1500), axis=0),
    "flat": lambda rng: np.c_[rng.random((2500, 2)), np.full(2500, 0.25)],
    "collinear": lambda rng: 3.0 + np.outer(rng.random(2500), rng.normal(size=3)),
    "huge spread": lambda rng: np.concatenate([rng.random((2500, 3)) * 1e-3, rng.normal(size=(20, 3)) * 1e8]),
    "far from origin": lambda rng: 1e6 + rng.random((3000, 3)),  # cell indices from rounded coordinates
    "integer lattice": lambda rng: rng.integers(0, 12, (3000, 3)).astype(float),  # ties and duplicates
}


@pytest.mark.parametrize("name", CLOUDS)
def test_knn_matches_brute_force(rng, name):
    p = rng.permutation(CLOUDS[name](rng))
    np.testing.assert_allclose(knn_mean_sq_dist(p), brute_knn(p), rtol=1e-9, atol=0)


@pytest.mark.parametrize("k", [1, 2, 7])
def test_knn_other_k(rng, k):
    p = clustered(rng, 3000)
    np.testing.assert_allclose(knn_mean_sq_dist(p, k=k), brute_knn(p, k=k), rtol=1e-9, atol=0)


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_knn_tiny_clouds_use_the_points_there_are(rng, n):
    p = rng.random((n, 3))
    np.testing.assert_allclose(knn_mean_sq_dist(p), brute_knn(p), rtol=1e-9, atol=0)


def test_knn_edge_cases():
    assert knn_mean_sq_dist(np.zeros((0, 3))).shape == (0,)
    np.testing.assert_array_equal(knn_mean_sq_dist([[1.0, 2.0, 3.0]]), [KNN_MIN_MEAN_SQ_DIST])  # no neighbour
    np.testing.assert_array_equal(knn_mean_sq_dist(np.ones((10, 3))), np.zeros(10))  # all coincident
    # Two copies of a point: each has the other at distance 0, and both count for the other points.
    line = [[0, 0, 0], [0, 0, 0], [0, 0, 2.0], [0, 0, 3.0], [0, 0, 10.0]]
    np.testing.assert_allclose(knn_mean_sq_dist(line), [13 / 3, 13 / 3, 9 / 3, 19 / 3, 213 / 3], rtol=1e-12)
    with pytest.raises(ValueError):
        knn_mean_sq_dist(np.zeros((4, 2)))
    with pytest.raises(ValueError):
        knn_mean_sq_dist([[0, 0, 0], [1, np.nan, 0]])


def test_knn_100k_points(rng):
    """The size of a NeRF-synthetic initialisation (no timing asserted); checked on a sample."""
    p = rng.random((100_000, 3)) * 2.6 - 1.3
    got = knn_mean_sq_dist(p)
    sample = rng.choice(len(p), 100, replace=False)
    np.testing.assert_allclose(got[sample], brute_knn(p, queries=sample), rtol=1e-9, atol=0)


def test_from_points(rng):
    points = np.concatenate([rng.random((300, 3)), np.zeros((4, 3))])  # four coincident: floor applies
    colors = rng.random((len(points), 3)).astype(np.float32)
    m = from_points(points, colors)
    n = len(points)
    assert len(m) == n and m.sh_degree == 3 and m.sh.shape == (n, 16, 3)
    np.testing.assert_array_equal(m.means, points.astype(np.float32))
    expected = 0.5 * np.log(np.maximum(brute_knn(points), KNN_MIN_MEAN_SQ_DIST))
    np.testing.assert_allclose(m.log_scales, np.repeat(expected[:, None], 3, axis=1), rtol=1e-6)
    np.testing.assert_allclose(m.scales[-4:], np.sqrt(KNN_MIN_MEAN_SQ_DIST), rtol=1e-6)  # ~3.2e-4
    np.testing.assert_array_equal(m.quats, np.tile([1, 0, 0, 0], (n, 1)))
    np.testing.assert_array_equal(m.opacity_logits, np.float32(logit(INIT_OPACITY)))
    np.testing.assert_allclose(m.opacities, INIT_OPACITY, rtol=1e-6)
    np.testing.assert_allclose(SH_C0 * m.sh[:, 0] + 0.5, colors, atol=1e-6)  # DC gives back the colour
    assert not m.sh[:, 1:].any()
    assert from_points(points, colors, sh_degree=0).sh.shape == (n, 1, 3)


def test_from_points_rejects_bad_input():
    with pytest.raises(ValueError, match="empty"):
        from_points(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError):
        from_points(np.zeros((5, 3)), np.zeros((4, 3)))


def test_random_points():
    points, colors = random_points(10_000, np.random.default_rng(7))
    assert points.shape == (10_000, 3) and points.dtype == np.float64
    assert colors.shape == (10_000, 3) and colors.dtype == np.float32
    assert points.min() >= -1.3 and points.max() <= 1.3 and np.ptp(points, axis=0).min() > 2.5
    sh_dc = (colors - 0.5) / SH_C0
    assert sh_dc.min() >= -1e-6 and sh_dc.max() < 1 / 255 + 1e-6 and sh_dc.max() > 0.9 / 255
    again = random_points(10_000, np.random.default_rng(7))
    np.testing.assert_array_equal(points, again[0])
    np.testing.assert_array_equal(colors, again[1])
    assert not np.array_equal(points, random_points(10_000, np.random.default_rng(8))[0])
    assert np.abs(random_points(100, np.random.default_rng(7), half_extent=0.5)[0]).max() <= 0.5
