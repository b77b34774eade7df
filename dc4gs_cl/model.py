"""Gaussian parameters on the host, as stored (before activation).

Layout (one row per Gaussian, float32, C-contiguous):
  means          (N, 3)      world position
  log_scales     (N, 3)      scale = exp(log_scale)
  quats          (N, 4)      rotation (w, x, y, z); normalised when used, not when stored
  opacity_logits (N,)        opacity = sigmoid(logit)
  sh             (N, K, 3)   K = (sh_degree + 1)^2 SH coefficients, coefficient-major, RGB innermost;
                             sh[:, 0] is the DC band ("f_dc"), sh[:, 1:] the rest ("f_rest")
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .constants import SH_C0, SH_MAX_DEGREE, sh_coeffs, sh_degree_of

# The parameter groups in their lane order per Gaussian: the device buffers, the Adam moments, the kernels'
# group indices (PARAM_<GROUP>, records.param_group_defines) and checkpoints all follow it.
PARAM_GROUPS = ("means", "log_scales", "quats", "opacity_logits", "sh")


def group_widths(sh_coeffs: int) -> dict[str, int]:
    """Floats per Gaussian of each parameter group, in PARAM_GROUPS order."""
    return {"means": 3, "log_scales": 3, "quats": 4, "opacity_logits": 1, "sh": 3 * sh_coeffs}


INIT_OPACITY = 0.1             # opacity of a freshly initialised Gaussian
KNN_NEIGHBOURS = 3             # initial scale: sqrt(mean squared distance to this many neighbours)
KNN_MIN_MEAN_SQ_DIST = 1e-7    # floor on that mean squared distance (Inria's simple-knn)


@dataclass
class GaussianModel:
    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray

    def __post_init__(self):
        n = len(self.means)
        self.means = np.ascontiguousarray(self.means, dtype=np.float32).reshape(n, 3)
        self.log_scales = np.ascontiguousarray(self.log_scales, dtype=np.float32).reshape(n, 3)
        self.quats = np.ascontiguousarray(self.quats, dtype=np.float32).reshape(n, 4)
        self.opacity_logits = np.ascontiguousarray(self.opacity_logits, dtype=np.float32).reshape(n)
        sh = np.ascontiguousarray(self.sh, dtype=np.float32)
        self.sh = sh.reshape(n, sh.shape[1] if sh.ndim == 3 else -1, 3)
        if self.sh.shape[1] not in [sh_coeffs(d) for d in range(SH_MAX_DEGREE + 1)]:
            raise ValueError(f"{self.sh.shape[1]} SH coefficients per channel is not (degree + 1)^2")

    def __len__(self) -> int:
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        """Highest SH degree the model stores."""
        return sh_degree_of(self.sh.shape[1])

    def groups(self) -> dict[str, np.ndarray]:
        """The parameters as PARAM_GROUPS rows: name -> (N, width) float32 (views of this model's arrays)."""
        widths = group_widths(self.sh.shape[1])
        return {k: getattr(self, k).reshape(len(self), widths[k]) for k in PARAM_GROUPS}

    @staticmethod
    def from_groups(groups: dict[str, np.ndarray]) -> "GaussianModel":
        """The inverse of groups()."""
        n = len(groups["means"])
        return GaussianModel(means=groups["means"], log_scales=groups["log_scales"], quats=groups["quats"],
                             opacity_logits=groups["opacity_logits"].reshape(n), sh=groups["sh"].reshape(n, -1, 3))

    # activations -------------------------------------------------------------------------------
    @property
    def scales(self) -> np.ndarray:
        return np.exp(self.log_scales)

    @property
    def opacities(self) -> np.ndarray:
        return sigmoid(self.opacity_logits)


def rgb_to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    """Colour in [0, 1] -> SH DC coefficient whose evaluated colour (C0 * dc + 0.5) is that colour."""
    return (np.asarray(rgb, dtype=np.float64) - 0.5) / SH_C0


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def logit(p: np.ndarray | float) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    return np.log(p / (1.0 - p))


@dataclass
class GaussianSet:
    """The Gaussians in training, on the host (densification, checkpoints): everything per Gaussian that must
    stay aligned: parameters (name -> (n, width) float32 arrays in PARAM_GROUPS order) and their Adam moments
    m and v (same names and shapes)."""
    params: dict[str, np.ndarray]
    m: dict[str, np.ndarray]
    v: dict[str, np.ndarray]
    aux: dict[str, np.ndarray] = field(default_factory=dict)   # (n,) values copied to clones and children

    @property
    def n(self) -> int:
        return len(self.params["means"])

    def keep(self, mask: np.ndarray) -> None:
        for group in (self.params, self.m, self.v, self.aux):
            for k in group:
                group[k] = group[k][mask]

    def append(self, new: dict[str, np.ndarray], parents: np.ndarray) -> None:
        """Add Gaussians with these parameters, zero moments, and the aux values of their parents."""
        for k in self.params:
            add = np.asarray(new[k], np.float32).reshape(-1, self.params[k].shape[1])
            self.params[k] = np.concatenate([self.params[k], add])
            self.m[k] = np.concatenate([self.m[k], np.zeros_like(add)])
            self.v[k] = np.concatenate([self.v[k], np.zeros_like(add)])
        for k in self.aux:
            self.aux[k] = np.concatenate([self.aux[k], self.aux[k][parents]])

    def scales(self) -> np.ndarray:
        return np.exp(self.params["log_scales"].astype(np.float64))

    def opacities(self) -> np.ndarray:
        return sigmoid(self.params["opacity_logits"][:, 0].astype(np.float64))


# initialisation --------------------------------------------------------------------------------
def from_points(points: np.ndarray, colors: np.ndarray, sh_degree: int = SH_MAX_DEGREE,
                opacity: float = INIT_OPACITY, scale_factor: float = 1.0) -> GaussianModel:
    """Gaussians initialised from a point cloud, as 3DGS does: one per point, colour (RGB in [0, 1])
    in the SH DC band and the other bands zero, isotropic scale sqrt(mean squared distance to the
    KNN_NEIGHBOURS nearest points, floored at KNN_MIN_MEAN_SQ_DIST) times scale_factor, identity rotation,
    opacity `opacity`. Raises ValueError on an empty cloud (loaders report that to the user
    first)."""
    points = np.asarray(points, dtype=np.float64)
    colors = np.asarray(colors, dtype=np.float64)
    n = len(points)
    if n == 0:
        raise ValueError("cannot initialise Gaussians from an empty point cloud")
    if colors.shape != (n, 3):
        raise ValueError(f"colors must have shape ({n}, 3), not {colors.shape}")
    mean_sq = np.maximum(knn_mean_sq_dist(points), KNN_MIN_MEAN_SQ_DIST)  # floored squared, as simple-knn
    sh = np.zeros((n, sh_coeffs(sh_degree), 3))
    sh[:, 0] = rgb_to_sh_dc(colors)
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    return GaussianModel(
        means=points,
        log_scales=np.repeat(0.5 * np.log(mean_sq)[:, None] + np.log(scale_factor), 3, axis=1),
        quats=quats,
        opacity_logits=np.full(n, logit(opacity)),
        sh=sh,
    )


def random_points(n: int, rng: np.random.Generator,
                  half_extent: float = 1.3) -> tuple[np.ndarray, np.ndarray]:
    """A cloud for scenes without SfM points, as 3DGS makes for NeRF-synthetic scenes: n points (float64)
    uniform in [-half_extent, half_extent]^3 and near-grey colours (float32) whose SH DC is uniform in
    [0, 1/255). The same rng state gives the same cloud."""
    points = rng.random((n, 3)) * (2.0 * half_extent) - half_extent
    sh_dc = rng.random((n, 3)) / 255.0
    return points, (SH_C0 * sh_dc + 0.5).astype(np.float32)


# k nearest neighbours --------------------------------------------------------------------------
_CELL_OCCUPANCY = 3.0          # target count of points in a point's own cell (itself included)
_KEY_BITS = 21                 # bits per axis in a cell key; indices wrap, which only adds candidates
_QUERY_BLOCK = 1 << 15         # queries whose 27 neighbour cells are looked up at once
_PAIR_CHUNK = 1 << 20          # (query, candidate) pairs held at once: bounds memory to ~100 MB
_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


RANDOM_INIT_POINTS = 100_000   # scenes without SfM points start from this many random Gaussians


def initial_model(points: np.ndarray | None, colors: np.ndarray | None, rng: np.random.Generator,
                  sh_degree: int = SH_MAX_DEGREE, **init) -> GaussianModel:
    """The Gaussians training starts from: the SfM points, or random points when a scene has none (init:
    from_points' opacity and scale_factor)."""
    if points is None:
        points, colors = random_points(RANDOM_INIT_POINTS, rng)
    return from_points(points, colors, sh_degree, **init)


def knn_mean_sq_dist(points: np.ndarray, k: int = KNN_NEIGHBOURS) -> np.ndarray:
    """Mean squared distance from each point to its k nearest other points, exact, in float64.

    Coincident points count, at distance 0. With P <= k points each one uses the P - 1 others; a single
    point has no neighbour and gets KNN_MIN_MEAN_SQ_DIST. Empty input gives an empty result.

    Method: exact duplicates are merged (kept as weights). Points are binned on a uniform grid whose cell
    holds a few points; each point's candidates are the points of the 3x3x3 cells around its own. The
    k-th candidate is the true k-th neighbour when it lies no farther than the block's nearest face (a
    face beyond the cloud's bounding box does not count); points that fail this test are searched again
    on a grid with cells twice as large (and at least the size typical of the cloud), and so on, until
    the few points left are searched by brute force. Memory stays bounded: pairs are made in chunks.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (P, 3), not {pts.shape}")
    if k < 1:
        raise ValueError(f"k must be at least 1, not {k}")
    n = len(pts)
    if n <= 1:
        return np.full(n, KNN_MIN_MEAN_SQ_DIST)
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite")
    k = min(k, n - 1)
    uniq, inverse, weight = _merge_duplicates(pts)
    lo = uniq.min(axis=0)
    h, h_median = _cell_sizes(uniq, lo)
    out = np.empty(len(uniq))
    todo = np.arange(len(uniq))
    while len(todo) * len(uniq) > _PAIR_CHUNK:  # until brute force on what is left is cheaper
        todo = _grid_pass(uniq, weight, lo, h, todo, k, out)
        h = max(2.0 * h, h_median)  # points that failed on a grid fine for a dense cluster: go typical
    _brute_force(uniq, weight, todo, k, out)
    return out[inverse]


def _merge_duplicates(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct points, the index of each input point among them, and how many inputs each stands for.
    Merging stops a pile of coincident points from defeating the grid."""
    order = np.lexsort(pts.T)
    s = pts[order]
    new = np.ones(len(s), dtype=bool)
    new[1:] = (s[1:] != s[:-1]).any(axis=1)
    inverse = np.empty(len(s), dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return s[new], inverse, np.diff(np.append(np.flatnonzero(new), len(s)))


def _cell_index(pts: np.ndarray, lo: np.ndarray, h: float) -> np.ndarray:
    return np.floor((pts - lo) / h).astype(np.int64)


def _cell_key(ijk: np.ndarray) -> np.ndarray:
    m = (1 << _KEY_BITS) - 1
    return ((ijk[..., 0] & m) << (2 * _KEY_BITS)) | ((ijk[..., 1] & m) << _KEY_BITS) | (ijk[..., 2] & m)


def _cell_sizes(pts: np.ndarray, lo: np.ndarray, target: float = _CELL_OCCUPANCY) -> tuple[float, float]:
    """Two cell sizes: at the first the median point shares its cell with about `target` - 1 others; at
    the second (smaller, where the cloud is clustered) so does the mean point, weighted by the work its
    cell costs. Starts from one cell over the whole cloud and shrinks as if the points filled 3D space;
    flat or clustered clouds (SfM) just take a few more steps."""
    h = float((pts.max(axis=0) - lo).max())
    if h == 0.0:
        return 1.0, 1.0  # a single distinct point
    h_median = None
    while True:
        keys = np.sort(_cell_key(_cell_index(pts, lo, h)))
        counts = np.diff(np.flatnonzero(np.r_[True, keys[1:] != keys[:-1], True]))
        per_point = np.repeat(counts, counts)
        median = float(np.partition(per_point, len(pts) // 2)[len(pts) // 2])
        mean = float(per_point.astype(np.float64).sum()) / len(pts)
        if h_median is None and median <= target:
            h_median = h
        if h_median is not None and mean <= 1.5 * target:
            return h, h_median
        h *= (target / (median if h_median is None else mean)) ** (1.0 / 3.0)


def _grid_pass(pts, weight, lo, h, todo, k, out) -> np.ndarray:
    """Search the points `todo` on the grid of cell size h; write the proven ones to `out`, return the
    rest."""
    ijk = _cell_index(pts, lo, h)
    keys = _cell_key(ijk)
    order = np.argsort(keys, kind="stable")
    skeys = keys[order]
    first = np.flatnonzero(np.r_[True, skeys[1:] != skeys[:-1]])
    cell_keys, cell_start = skeys[first], first
    cell_count = np.diff(np.append(first, len(skeys)))
    top = ijk.max(axis=0)
    # Rounding in cell indices and face positions is a few ulps of the coordinates: stay that far inside.
    margin = 1e-14 * (float(np.abs(pts).max()) + 3.0 * h)
    todo = todo[np.argsort(keys[todo], kind="stable")]  # sorted queries make the lookups cache-friendly
    failed = []
    for b in range(0, len(todo), _QUERY_BLOCK):
        q = todo[b:b + _QUERY_BLOCK]
        qijk, x = ijk[q], pts[q]
        starts = np.empty((len(q), 27), dtype=np.int64)
        counts = np.empty((len(q), 27), dtype=np.int64)
        for o, off in enumerate(_OFFSETS):
            nk = _cell_key(qijk + off)
            pos = np.minimum(np.searchsorted(cell_keys, nk), len(cell_keys) - 1)
            starts[:, o] = cell_start[pos]
            counts[:, o] = np.where(cell_keys[pos] == nk, cell_count[pos], 0)
        # Distance to the nearest face of the 3x3x3 block; faces with no point beyond them do not count.
        below = np.where(qijk <= 1, np.inf, x - (lo + (qijk - 1) * h))
        above = np.where(qijk + 1 >= top, np.inf, lo + (qijk + 2) * h - x)
        radius = np.maximum(np.minimum(below, above).min(axis=1) - margin, 0.0)
        pairs = counts.sum(axis=1)
        ends = np.cumsum(pairs)
        s = 0
        while s < len(q):
            e = max(s + 1, int(np.searchsorted(ends, ends[s] - pairs[s] + _PAIR_CHUNK, side="right")))
            mean, kth, done = _k_nearest(pts, weight, order, q[s:e], starts[s:e], counts[s:e], k)
            ok = done & (kth <= radius[s:e] ** 2)
            out[q[s:e][ok]] = mean[ok]
            failed.append(q[s:e][~ok])
            s = e
    return np.concatenate(failed)


def _brute_force(pts, weight, todo, k, out) -> None:
    """Search the points `todo` against every point, a few queries at a time."""
    n = len(pts)
    step = max(1, _PAIR_CHUNK // n)
    for s in range(0, len(todo), step):
        q = todo[s:s + step]
        starts, counts = np.zeros((len(q), 1), dtype=np.int64), np.full((len(q), 1), n)  # one run: all
        out[q] = _k_nearest(pts, weight, np.arange(n), q, starts, counts, k)[0]


def _k_nearest(pts, weight, order, q, starts, counts, k):
    """Weighted k smallest squared distances from each query to its candidates (given as runs of the
    sorted point order): (mean, k-th distance, whether k were found)."""
    flat = counts.ravel()
    run_start = np.cumsum(flat) - flat
    cand = order[np.repeat(starts.ravel() - run_start, flat) + np.arange(flat.sum())]
    per_query = counts.sum(axis=1)
    seg = np.cumsum(per_query) - per_query
    diff = pts[cand] - np.repeat(pts[q], per_query, axis=0)
    d = np.einsum("ij,ij->i", diff, diff)
    # A point's own entry stands for its duplicates (distance 0), or for nothing when it has none.
    w = weight[cand] - (cand == np.repeat(q, per_query))
    d[w == 0] = np.inf
    need = np.full(len(q), k, dtype=np.int64)
    total = np.zeros(len(q))
    kth = np.zeros(len(q))
    for _ in range(k):  # each round takes every copy of the current smallest distance
        m = np.minimum.reduceat(d, seg)
        hit = d == np.repeat(m, per_query)
        take = np.minimum(np.add.reduceat(np.where(hit, w, 0), seg), need)
        got = take > 0
        total[got] += take[got] * m[got]
        kth[got] = m[got]
        need -= take
        d[hit], w[hit] = np.inf, 0
    return total / k, kth, need == 0
