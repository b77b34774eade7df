"""Growing, shrinking and limiting the Gaussians: parameters and Adam moments together, in one place.

Host copies are enough here: densification runs every few hundred iterations, and the trainer uploads
the result in one go. New Gaussians start with zero Adam moments (as the 3DGS code does).
"""
from __future__ import annotations

import math

import numpy as np

from ..geometry import principal_axis, quat_to_rotmat
from ..model import GaussianSet, logit, sigmoid

SPLIT_CHILDREN = 2
SPLIT_SCALE_DIVISOR = 1.6   # = 0.8 * SPLIT_CHILDREN in the 3DGS code
SPLIT_GROWTH = SPLIT_CHILDREN - 1   # Gaussians a split adds (its children replace it); a clone adds one


def cap_growth(budget: int, candidates: list[tuple[np.ndarray, np.ndarray, int]]) -> list[np.ndarray]:
    """Which candidates a densification step may take when it may add at most `budget` Gaussians.
    candidates: (mask, score, growth) per operation (clone, split): the Gaussians that qualify, a score per
    Gaussian that ranks them (criterion over its threshold, so clones and splits compare without units) and
    how many Gaussians each adds. The highest scores win, ties to the lower index then the earlier operation;
    the masks returned keep the winners."""
    rows = [(-score[mask], np.flatnonzero(mask), np.full(int(mask.sum()), op), np.full(int(mask.sum()), growth))
            for op, (mask, score, growth) in enumerate(candidates)]
    neg_score, index, op, growth = (np.concatenate(col) for col in zip(*rows))
    order = np.lexsort((op, index, neg_score))
    taken = order[np.cumsum(growth[order]) <= max(budget, 0)]
    out = [np.zeros_like(mask) for mask, _, _ in candidates]
    for k, mask in enumerate(out):
        mask[index[taken][op[taken] == k]] = True
    return out


def clone(gs: GaussianSet, mask: np.ndarray) -> int:
    """Exact copies of the selected Gaussians (appended)."""
    idx = np.flatnonzero(mask)
    gs.append({k: v[idx] for k, v in gs.params.items()}, idx)
    return len(idx)


def split_random(gs: GaussianSet, mask: np.ndarray, rng: np.random.Generator) -> int:
    """The 3DGS split: each selected Gaussian is replaced by SPLIT_CHILDREN children at mu + R (S eps),
    eps ~ N(0, I), with scales S / 1.6 and everything else copied."""
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return 0
    parents = {k: np.repeat(v[idx], SPLIT_CHILDREN, axis=0) for k, v in gs.params.items()}
    scales = np.exp(parents["log_scales"].astype(np.float64))
    offsets = rng.normal(size=scales.shape) * scales
    rot = quat_to_rotmat(parents["quats"])
    parents["means"] = parents["means"] + np.einsum("nij,nj->ni", rot, offsets)
    parents["log_scales"] = np.log(scales / SPLIT_SCALE_DIVISOR)
    replace_with_children(gs, idx, parents)
    return len(idx)


def split_at(gs: GaussianSet, idx: np.ndarray, x: np.ndarray, other_scale: float = 1.0) -> int:
    """The DC-guided split: each Gaussian idx[i] becomes two children on its principal axis, cut at
    normalised position x[i] (spec section 5): centres mu - 3 sigma (1 - x) p and mu + 3 sigma x p, scales
    along the axis sigma x and sigma (1 - x) and along the other two axes the parent's times other_scale (1 in
    the paper), opacities o x and o (1 - x), rotation and colour copied; the children's Adam moments start at
    zero."""
    if len(idx) == 0:
        return 0
    children = split_children({k: v[idx] for k, v in gs.params.items()}, x, other_scale)
    # Children of one parent in a row, as replace_with_children expects.
    stacked = {k: np.stack([c[k] for c in children], axis=1).reshape(2 * len(idx), -1) for k in children[0]}
    replace_with_children(gs, idx, stacked)
    return len(idx)


def split_children(params: dict[str, np.ndarray], x: np.ndarray,
                   other_scale: float = 1.0) -> list[dict[str, np.ndarray]]:
    """split_at's two children of the Gaussians params (float64)."""
    p = {k: v.astype(np.float64) for k, v in params.items()}
    axis, sigma, direction = principal_axis(p["log_scales"], p["quats"])
    x = np.asarray(x, np.float64)
    opacity = sigmoid(p["opacity_logits"][:, 0])
    others = p["log_scales"] + math.log(other_scale)
    children = []
    for offset, fraction in ((-3 * sigma * (1 - x), x), (3 * sigma * x, 1 - x)):
        log_scales = others.copy()
        log_scales[np.arange(len(x)), axis] = np.log(sigma * fraction)
        children.append({"means": p["means"] + offset[:, None] * direction, "log_scales": log_scales,
                         "opacity_logits": logit(opacity * fraction)[:, None], "quats": p["quats"], "sh": p["sh"]})
    return children


def replace_with_children(gs: GaussianSet, idx: np.ndarray, children: dict[str, np.ndarray]) -> None:
    """Remove the Gaussians idx and append their children (len(children) is a multiple of len(idx), the
    children of each parent in a row)."""
    per_parent = len(children["means"]) // max(len(idx), 1)
    gs.append(children, np.repeat(idx, per_parent))
    keep = np.ones(gs.n, bool)
    keep[idx] = False
    gs.keep(keep)


def prune(gs: GaussianSet, mask: np.ndarray) -> int:
    gs.keep(~mask)
    return int(mask.sum())
