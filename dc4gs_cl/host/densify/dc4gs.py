"""DC4GS on the host (../shared/docs/dc4gs-spec.md sections 3 to 5): its settings, the DC-weighted split
criterion (DCC), and the split position from the candidates' costs (DCS; the split itself is ops.split_at).

The statistics are gathered on the device (kernels/rasterize_backward.cl, kernels/densify_stats.cl, what
statistics.StatisticsSpec asks for); a strategy reads the window at a densification step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .statistics import DC_WEIGHTED, DCC_ABS, VIEWS, Criterion

POOLINGS = ("view", "window")       # per view (the paper) or over the window (the authors' release)
SPLIT_PICKS = ("poly", "argmin", "dense", "middle")   # middle: DCS' split at x = 0.5, no costs (an ablation)
DCC_READINGS = ("abs", "base")
FIVE_CANDIDATES = 5                 # the paper's candidate count
DENSE_CANDIDATES = 59               # --split-pick dense without --split-candidates
CONSTANT_COSTS = 1e-7               # relative spread below which the costs carry no preference: split in the middle
NEGLIGIBLE_COSTS = 1e-12            # ... and costs this small are float noise of vanishing gradients


@dataclass(frozen=True)
class DC4GSConfig:
    """DC4GS' settings; off unless dcc or dcs (every setting is still checked, so that a mistyped flag never
    passes silently)."""
    dcc: bool = False               # DC-weighted split criterion
    dcs: bool = False               # DC-guided split placement
    pooling: str = "view"
    split_pick: str = "poly"
    candidates: int | None = None   # odd; None: FIVE_CANDIDATES, or DENSE_CANDIDATES with split_pick "dense"
    dcc_reading: str = "base"       # base: (1 - kappa) x the base's own per-view term; abs: (1 - kappa) |ghat|
    track: float = 0.0              # split costs only while the running split criterion >= track x threshold (0: exact)
    other_scale: float = 1.0        # DCS children's other two axes x this (1, the paper's: kept; release: const_scale)
    cost_every: int = 1             # split costs from every this-many-th iteration's view only (1: every view, exact)

    def __post_init__(self):
        if problems := self.problems():
            raise ValueError("; ".join(problems))

    @property
    def enabled(self) -> bool:
        return self.dcc or self.dcs

    @property
    def costs_pick(self) -> bool:
        """Whether DCS' split position comes from the candidates' costs (not with split_pick middle)."""
        return self.dcs and self.split_pick != "middle"

    @property
    def candidate_count(self) -> int:
        if self.candidates is not None:
            return self.candidates
        return DENSE_CANDIDATES if self.split_pick == "dense" else FIVE_CANDIDATES

    @property
    def label(self) -> str:
        """DC4GS, DCC or DCS: what a strategy's name gets appended."""
        return "DC4GS" if self.dcc and self.dcs else ("DCC" if self.dcc else "DCS")

    def problems(self) -> list[str]:
        """What is wrong with these settings, named by their command-line flags (empty: nothing)."""
        out = [f"{flag} {value!r} is not one of {', '.join(allowed)}"
               for flag, value, allowed in (("--dc-pooling", self.pooling, POOLINGS),
                                            ("--split-pick", self.split_pick, SPLIT_PICKS),
                                            ("--dcc-reading", self.dcc_reading, DCC_READINGS))
               if value not in allowed]
        if self.candidate_count < 3 or self.candidate_count % 2 == 0:
            out.append(f"--split-candidates {self.candidate_count} must be odd and at least 3")
        if not 0 <= self.track <= 1:
            out.append(f"--dcs-track {self.track} must lie in [0, 1]")
        if not 0 < self.other_scale <= 1:
            out.append(f"--dcs-other-scale {self.other_scale} must lie in (0, 1]")
        if self.cost_every < 1:
            out.append(f"--dcs-every {self.cost_every} must be at least 1")
        elif self.cost_every > 1 and self.pooling == "window":
            # window pooling costs the sides' running sums at every visible view, which a skipped view cannot add to
            out.append(f"--dcs-every {self.cost_every} needs --dc-pooling view")
        return out


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
