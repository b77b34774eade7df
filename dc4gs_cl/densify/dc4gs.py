"""DC4GS on the host (../shared/docs/dc4gs-spec.md sections 3 to 5): the DC-weighted split criterion (DCC),
and the split position from the candidates' costs (DCS; the split itself is ops.split_at). Its settings are
config.DC4GSConfig.

The statistics are gathered on the device (kernels/rasterize_backward.cl, kernels/densify_stats.cl, what
statistics.StatisticsSpec asks for); a strategy reads the window at a densification step.
"""
from __future__ import annotations

import numpy as np

from ..statistics import DC_WEIGHTED, DCC_ABS, VIEWS, Criterion

CONSTANT_COSTS = 1e-7               # relative spread below which the costs carry no preference: split in the middle
NEGLIGIBLE_COSTS = 1e-12            # ... and costs this small are float noise of vanishing gradients


def dcc_criterion(base: Criterion, reading: str) -> Criterion:
    """DCC's split criterion on a base: (1 - kappa) times the base's own per-view term (reading "base", the
    paper's), or times the homodirectional gradient (reading "abs"), over the base's count."""
    return Criterion(DC_WEIGHTED[base.total], base.count) if reading == "base" else Criterion(DCC_ABS, VIEWS)


def candidate_positions(n: int) -> np.ndarray:
    """Normalised positions x_k = (k + 1) / (n + 1) along the diameter (x = 0 at mu - 3 sigma p)."""
    return (np.arange(n) + 1.0) / (n + 1)


def search_interval(n: int) -> tuple[float, float]:
    """[1/(2(n+1)), 1 - 1/(2(n+1))]: [1/12, 11/12] for 5 candidates, as the release searches."""
    half = 0.5 / (n + 1)
    return half, 1.0 - half


def interpolating_polynomials(costs: np.ndarray) -> np.ndarray:
    """(M, n) costs at the candidate positions -> (M, n) coefficients, lowest power first, of the degree
    n - 1 polynomial through them (exact interpolation: the Vandermonde system solved once)."""
    x = candidate_positions(costs.shape[1])
    return np.linalg.solve(np.vander(x, increasing=True), np.asarray(costs, np.float64).T).T


def polynomial_minimum(coeffs: np.ndarray, lo: float, hi: float, grid: int = 2049) -> np.ndarray:
    """x in [lo, hi] minimising each polynomial exactly: a dense grid finds the best basin, bisection on the
    derivative pins a critical point in either grid cell beside the best grid point to float64 precision
    (a minimum within a cell of an end point included), and the lowest of those and the grid point wins."""
    if len(coeffs) == 0:
        return np.zeros(0)
    poly = np.polynomial.polynomial
    xs = np.linspace(lo, hi, grid)
    best = poly.polyval(xs, coeffs.T).argmin(axis=1)               # polyval gives (M, grid)
    deriv = np.stack([poly.polyder(c) for c in coeffs])

    def slope(at):                                                 # p'(at[m]) of each polynomial m
        return np.einsum("mk,mk->m", deriv, at[:, None] ** np.arange(deriv.shape[1]))

    def critical_point(a, b):                                      # a minimum inside [a, b], else nan
        bracketed = (slope(a) < 0) & (slope(b) > 0)
        for _ in range(60):
            mid = 0.5 * (a + b)
            down = slope(mid) < 0
            a, b = np.where(down, mid, a), np.where(down, b, mid)
        return np.where(bracketed, 0.5 * (a + b), np.nan)

    at = xs[best]
    candidates = np.stack([at, critical_point(xs[np.maximum(best - 1, 0)], at),
                           critical_point(at, xs[np.minimum(best + 1, grid - 1)])], 1)
    values = np.einsum("mk,mjk->mj", coeffs, candidates[:, :, None] ** np.arange(coeffs.shape[1]))
    return candidates[np.arange(len(at)), np.where(np.isnan(values), np.inf, values).argmin(axis=1)]


def split_positions(costs: np.ndarray, pick: str) -> np.ndarray:
    """(M, n) candidate costs -> (M,) split positions in (0, 1). Costs that do not prefer any position
    (all zero or float noise, constant, or not finite) split in the middle, 0.5."""
    costs = np.asarray(costs, np.float64)
    n = costs.shape[1]
    x = candidate_positions(n)
    if pick == "poly":
        out = polynomial_minimum(interpolating_polynomials(costs), *search_interval(n))
    else:   # argmin and dense: the best candidate (dense differs only in how many there are)
        out = x[np.argmin(costs, axis=1)]
    spread = costs.max(axis=1) - costs.min(axis=1)
    largest = np.abs(costs).max(axis=1)
    flat = ~np.isfinite(costs).all(axis=1) | (spread <= CONSTANT_COSTS * largest) | (largest <= NEGLIGIBLE_COSTS)
    return np.where(flat, 0.5, out)
