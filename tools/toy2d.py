"""The paper's 2D toy study of the DC-guided split (appendix "Effect of sampling resolution and selection
method"): where to cut one Gaussian that covers two (or three) structures, chosen by dense argmin
(N = 59), polynomial fit (N = 5) or argmin (N = 5) of the DC-based split costs, scored by SSIM.

    python tools/toy2d.py [--cases 10000] [--seed 0] [--size 64] [--gt gaussians|regions]
                          [--loss l2|train] [--jobs 2] [--json PATH]

The paper does not publish its generator; these are ours. Each case draws from its own generator
np.random.default_rng([seed, case]), so a case does not depend on --cases or --jobs. Pixel centres at +0.5.

Parent (both generators): one 2D Gaussian near the centre (mean within +-5% of the size), sigma along
its principal axis p uniform in [0.07, 0.13] size, the other axis 0.3 to 0.7 of it, opacity uniform in
[0.8, 0.95], p at a uniform angle within +-40 degrees of the structure's normal n (n at a uniform angle).
x* ~ U(0.25, 0.75) is where the main structure change crosses the axis, in the split's normalised
position (x = 0 at mu - 3 sigma p, 1 at mu + 3 sigma p). The parent is held as a 3D Gaussian in the plane
z = 0 (third scale tiny, rotation about z) so our code paths take it as they are; its 2D covariance is
the xy block of R S^2 R^T (no EWA dilation: the toy lives in pixel space). Its colour is the least-squares
fit to the ground truth; it is blended over the background as the rasterizer blends: alpha =
min(0.99, o exp(power)), pairs with alpha < 1/255 skipped, front to back.

Ground truth, --gt gaussians (default; over black): the parent's own children at x* (algorithm 4, by
split_at), each with its own colour (the colour rule below); with probability 1/4 the right child split
again at U(0.3, 0.7) with a third colour. A split at x* rebuilds a two-child ground truth exactly, so the
score measures placement.
Ground truth, --gt regions (size x size RGB, background = its mean colour):
- a main boundary f(q) = n.(q - b) + k ((q - b).t)^2 = 0 through b = mu + (6 x* - 3) sigma p (tangent t;
  half the cases straight, half slightly curved, |k| <= 0.6 / size: a few pixels' bow over the parent);
- with probability 1/4 a third region: a straight line at a uniform angle through a point on the axis
  beyond b cuts region B into B and C (a T junction);
- region colours uniform in [0.05, 0.95]^3, neighbours at least 0.3 apart (redrawn until they are), each
  with a mild linear gradient (up to +-0.15 per image side per channel), clipped to [0, 1].
  Without a refinement after the split, SSIM here favours splits that change the parent least
  (algorithm 4's children meet at their 3 sigma tails and split the parent's opacity between them): in
  our runs the unsplit parent scores best and the split at the edge worst. Kept to show that, and for
  the costs on an edge.

Protocol per case:
1. Per-pixel positional gradients g_j = dL/dimage_j . dimage_j/dmu' of the parent's 2D mean (float64,
   analytic), L = mean squared error (--loss l2, default) or the training loss 0.8 L1 + 0.2 (1 - SSIM)
   (--loss train, dL/dimage from dc4gs_cl.reference.loss).
2. Split costs as algorithms 2-3 state them: candidates from dc4gs_cl.reference.dc4gs.candidate_points,
   a pixel takes part when blended and |g| > 0, it is left of candidate k when (end - x_k).(q - x_k) < 0,
   J = split_costs_from_sums (cost_side = (1 - kappa_side) |ghat_side|). Gradients are in pixel units
   (the trainer's NDC scaling is isotropic on a square image and changes no position).
3. Split positions from dc4gs_cl.densify.dc4gs.split_positions: "dense" with 59 candidates (our dense pick
   takes an odd count; the paper says 60), "poly" and "argmin" with 5. References: the middle x = 0.5,
   the true crossing x = x*, the unsplit parent, and the random 3DGS split (densify.ops.split_random: two
   children at mu + R S eps, scales / 1.6, opacity copied).
4. Children from densify.ops.split_at (the paper's algorithm 4), then every child colour refitted to the
   ground truth by least squares (the image is linear in the colours for fixed geometry and order;
   colours unconstrained), so the score measures placement alone. No gradient-descent refinement.
5. Score: SSIM (dc4gs_cl.reference.loss.ssim_map: 11 x 11 Gaussian window, sigma 1.5, zero padding)
   averaged over the whole image ("image") and over the parent's footprint, the pixels it blends
   ("footprint"; outside it every method shows the same background).
Reported per method: mean, median and IQR (Q3 - Q1) of each score beside the paper's figures, the
median |x - x*|, the case-by-case wins of poly over argmin, and how often poly lands on an end of its
search interval [1/12, 11/12] (the quartic through 5 samples turning down past the outer ones).
"""
from __future__ import annotations

import argparse
import json
import time
from functools import partial
from multiprocessing import Pool

import numpy as np

from dc4gs_cl import constants as K
from dc4gs_cl.config import DENSE_CANDIDATES
from dc4gs_cl.densify.dc4gs import search_interval, split_positions
from dc4gs_cl.densify.ops import split_at, split_random
from dc4gs_cl.geometry import quat_to_rotmat
from dc4gs_cl.model import GaussianSet, logit
from dc4gs_cl.reference.dc4gs import candidate_points, split_costs_from_sums
from dc4gs_cl.reference.loss import loss_gradient, ssim_map
from dc4gs_cl.reference.loss import loss_value as train_loss

PICKS = {"dense": DENSE_CANDIDATES, "poly": 5, "argmin": 5}     # pick -> candidates
METHODS = ("dense", "poly", "argmin", "middle", "boundary", "random", "parent")
PAPER = {"dense": (0.983, None, None), "poly": (0.979, 0.987, 0.0136), "argmin": (0.977, 0.983, 0.0194)}
MIN_CONTRAST = 0.3


# ground truth and parent --------------------------------------------------------------------------------

def pixel_centres(size: int) -> np.ndarray:
    ys, xs = np.mgrid[0:size, 0:size]
    return np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1).astype(np.float64)      # (P, 2) as (x, y)


def _colours(rng, n):
    c = [rng.uniform(0.05, 0.95, 3)]
    while len(c) < n:       # each new region against region B (index 1) or A for B itself
        cand = rng.uniform(0.05, 0.95, 3)
        if np.linalg.norm(cand - c[min(len(c) - 1, 1)]) >= MIN_CONTRAST:
            c.append(cand)
    return c


def make_parent(mean2d, sigma, minor, angle, opacity) -> dict[str, np.ndarray]:
    """A 2D Gaussian held as a 3D one in the plane z = 0: (1, width) parameter arrays as GaussianSet keeps."""
    return {"means": np.array([[mean2d[0], mean2d[1], 0.0]]),
            "log_scales": np.log([[sigma, minor, 1e-3 * minor]]),
            "quats": np.array([[np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]]),
            "opacity_logits": np.array([[float(logit(opacity))]]),
            "sh": np.zeros((1, 3))}


def make_case(seed: int, index: int, size: int = 64, gt: str = "gaussians") -> dict:
    rng = np.random.default_rng([seed, index])
    q = pixel_centres(size)
    centre = np.full(2, size / 2)
    sigma = rng.uniform(0.07, 0.13) * size
    minor = sigma * rng.uniform(0.3, 0.7)
    phi = rng.uniform(0, 2 * np.pi)
    n, t = np.array([np.cos(phi), np.sin(phi)]), np.array([-np.sin(phi), np.cos(phi)])
    angle = phi + np.deg2rad(rng.uniform(-40, 40))
    p = np.array([np.cos(angle), np.sin(angle)])
    mu = centre + rng.uniform(-0.05, 0.05, 2) * size
    x_true = rng.uniform(0.25, 0.75)
    parent = make_parent(mu, sigma, minor, angle, rng.uniform(0.8, 0.95))
    three = bool(rng.random() < 0.25)
    if gt == "regions":
        b = mu + (6 * x_true - 3) * sigma * p
        bend = rng.uniform(-0.6, 0.6) / size if rng.random() < 0.5 else 0.0
        label = ((q - b) @ n + bend * ((q - b) @ t) ** 2 > 0).astype(int)            # 0: A, 1: B
        if three:
            b2 = mu + (6 * rng.uniform(x_true, 1.0) - 3) * sigma * p
            psi = rng.uniform(0, 2 * np.pi)
            label[(label == 1) & ((q - b2) @ np.array([np.cos(psi), np.sin(psi)]) > 0)] = 2
        colours = _colours(rng, 3 if three else 2)
        slopes = rng.uniform(-0.15, 0.15, (len(colours), 3, 2))
        rel = (q - centre) / size
        image = np.stack([np.clip(colours[k] + rel @ slopes[k].T, 0, 1) for k in range(len(colours))])
        image = image[label, np.arange(len(q))]                                      # (P, 3)
        bg = image.mean(0)
    else:   # "gaussians": the parent's own children at x* (algorithm 4), one colour each, over black
        hidden = _gaussian_set(parent, 1)
        split_at(hidden, np.array([0]), np.array([x_true]))
        if three:           # the right child split again: L, RL, RR
            split_at(hidden, np.array([1]), np.array([rng.uniform(0.3, 0.7)]))
        m, cov, o = gaussians_2d(hidden.params)
        w, T, *_ = blend(q, m[None], cov[None], o[None])
        bg = np.zeros(3)
        image = w[0] @ np.array(_colours(rng, hidden.n)) + T[0, :, None] * bg
    return {"gt": image, "bg": bg, "size": size, "x_true": x_true, "three": three, "rng": rng, "parent": parent}


def _gaussian_set(params, copies):
    p = {k: np.repeat(np.asarray(v, np.float32), copies, axis=0) for k, v in params.items()}
    return GaussianSet(p, {k: np.zeros_like(v) for k, v in p.items()}, {k: np.zeros_like(v) for k, v in p.items()})


# rendering (the rasterizer's blending, batched over B sets of G Gaussians in front-to-back order) -----------

def gaussians_2d(params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parameter arrays (n, .) -> 2D means (n, 2), covariances (n, 2, 2), opacities (n,)."""
    s = np.exp(np.asarray(params["log_scales"], np.float64))
    r = quat_to_rotmat(params["quats"])[:, :2]
    cov = np.einsum("nik,nk,njk->nij", r, s * s, r)
    opacity = 1 / (1 + np.exp(-np.asarray(params["opacity_logits"], np.float64)[:, 0]))
    return np.asarray(params["means"], np.float64)[:, :2], cov, opacity


def blend(q, means, cov, opacity):
    """means (B, G, 2), cov (B, G, 2, 2), opacity (B, G) -> per pixel weights alpha T_before (B, P, G),
    final T (B, P), and alpha, exp(power), offsets q - mean and inverse covariances for gradients."""
    d = q[None, :, None, :] - means[:, None]                                       # (B, P, G, 2)
    inv = np.linalg.inv(cov)
    dx, dy = d[..., 0], d[..., 1]
    G = np.exp(-0.5 * (inv[:, None, :, 0, 0] * dx * dx + 2 * inv[:, None, :, 0, 1] * dx * dy
                       + inv[:, None, :, 1, 1] * dy * dy))
    alpha = np.minimum(K.ALPHA_MAX, opacity[:, None] * G)
    alpha = np.where(alpha >= K.ALPHA_MIN, alpha, 0.0)
    t_after = np.cumprod(1 - alpha, axis=2)
    w = alpha * np.concatenate([np.ones_like(alpha[..., :1]), t_after[..., :-1]], axis=2)
    return w, t_after[..., -1], alpha, G, d, inv


def fit_colours(w, T, gt, bg):
    """Least-squares colours (B, G, 3) and the images (B, P, 3) they give."""
    wt = w.transpose(0, 2, 1)
    c = np.linalg.solve(wt @ w + 1e-12 * np.eye(w.shape[2]), wt @ (gt[None] - T[..., None] * bg))
    return c, w @ c + T[..., None] * bg


def dloss_dimage(img, gt, size, loss):
    """dL/dimage (P, 3) for the mean squared error or the training loss."""
    if loss == "l2":
        return 2 * (img - gt) / img.size
    return loss_gradient(img.reshape(size, size, 3), gt.reshape(size, size, 3)).reshape(-1, 3)


def loss_value(img, gt, size, loss) -> float:
    if loss == "l2":
        return float(((img - gt) ** 2).mean())
    return train_loss(img.reshape(size, size, 3), gt.reshape(size, size, 3))


def parent_gradients(case, mean2d=None, colour=None, loss="l2"):
    """Per-pixel dL/dmu' (P, 2) of the parent's 2D mean, which pixels it blends (P,), its image and colour.
    mean2d and colour default to the parent's mean and its least-squares colour (the test moves them)."""
    q, gt, bg = pixel_centres(case["size"]), case["gt"], case["bg"]
    means, cov, o = gaussians_2d(case["parent"])
    if mean2d is not None:
        means = np.asarray(mean2d, np.float64)[None]
    w, T, alpha, G, d, inv = blend(q, means[None], cov[None], o[None])
    if colour is None:
        colour, _ = fit_colours(w, T, gt, bg)
    colour = np.asarray(colour, np.float64).reshape(3)
    img = w[0] @ colour[None] + T[0, :, None] * bg
    live = (alpha[0, :, 0] > 0) & (o[0] * G[0, :, 0] < K.ALPHA_MAX)   # no gradient where alpha clamps
    dalpha = np.where(live, o[0] * G[0, :, 0], 0.0)[:, None] * (d[0, :, 0] @ inv[0, 0].T)
    dL = dloss_dimage(img, gt, case["size"], loss) @ (colour - bg)
    return dL[:, None] * dalpha, alpha[0, :, 0] > 0, img, colour


def split_costs(case, g, blended, n: int) -> np.ndarray:
    """J (n,) at the n candidates, as algorithms 2-3: pixels blended with |g| > 0, left when
    (end - x_k).(q - x_k) < 0; the sums (u_x, u_y, count, |g_x|, |g_y|) go to split_costs_from_sums."""
    q = pixel_centres(case["size"])
    norm = np.linalg.norm(g, axis=1)
    take = blended & (norm > 0)
    g, q, norm = g[take], q[take], norm[take]
    f = np.column_stack([g / norm[:, None], np.ones(len(g)), np.abs(g)])               # (P', 5)
    par = case["parent"]
    cand, end = candidate_points(par["means"], par["log_scales"], par["quats"], n)
    cand, end = cand[0, :, :2], end[0, :2]
    left = np.einsum("ki,kpi->kp", end - cand, q[None] - cand[:, None]) < 0            # (n, P')
    return split_costs_from_sums((left.astype(np.float64) @ f)[None], f.sum(0)[None])[0]


def run_case(index: int, seed: int = 0, size: int = 64, gt: str = "gaussians", loss: str = "l2") -> dict:
    case = make_case(seed, index, size, gt)
    g, blended, _, _ = parent_gradients(case, loss=loss)
    x = {pick: float(split_positions(split_costs(case, g, blended, n)[None], pick)[0]) for pick, n in PICKS.items()}
    x["middle"], x["boundary"] = 0.5, case["x_true"]
    placed = list(x)
    guided = _gaussian_set(case["parent"], len(placed))
    split_at(guided, np.arange(len(placed)), np.array([x[m] for m in placed]))
    rand = _gaussian_set(case["parent"], 1)
    split_random(rand, np.array([True]), case["rng"])
    means, cov, o = gaussians_2d({k: np.concatenate([guided.params[k], rand.params[k]]) for k in guided.params})
    B = len(placed) + 1
    w, T, *_ = blend(pixel_centres(size), means.reshape(B, 2, 2), cov.reshape(B, 2, 2, 2), o.reshape(B, 2))
    _, imgs = fit_colours(w, T, case["gt"], case["bg"])
    pm, pc, po = gaussians_2d(case["parent"])
    w1, T1, *_ = blend(pixel_centres(size), pm[None], pc[None], po[None])
    _, parent_img = fit_colours(w1, T1, case["gt"], case["bg"])
    imgs = np.concatenate([imgs, parent_img])                                         # (B + 1, P, 3)
    stack = imgs.reshape(-1, size, size, 3).transpose(1, 2, 3, 0)                      # (H, W, 3, methods)
    smap = ssim_map(stack, case["gt"].reshape(size, size, 3, 1)).mean(axis=2)          # (H, W, methods)
    foot = blended.reshape(size, size)
    names = placed + ["random", "parent"]
    return {"x": x, "x_true": case["x_true"], "three": case["three"],
            "image": dict(zip(names, smap.mean(axis=(0, 1)).tolist())),
            "footprint": dict(zip(names, smap[foot].mean(axis=0).tolist()))}


# the study ---------------------------------------------------------------------------------------------

def summarise(results: list[dict]) -> dict:
    out = {}
    for score in ("image", "footprint"):
        out[score] = {}
        for m in METHODS:
            v = np.array([r[score][m] for r in results])
            q1, med, q3 = np.percentile(v, [25, 50, 75])
            out[score][m] = {"mean": float(v.mean()), "median": float(med), "iqr": float(q3 - q1),
                             "min": float(v.min())}
        a, b = (np.array([r[score][m] for r in results]) for m in ("poly", "argmin"))
        out[score]["poly_vs_argmin"] = {"wins": int((a > b + 1e-12).sum()), "losses": int((a < b - 1e-12).sum()),
                                        "ties": int((np.abs(a - b) <= 1e-12).sum())}
    out["x_error"] = {m: float(np.median([abs(r["x"][m] - r["x_true"]) for r in results]))
                      for m in ("dense", "poly", "argmin", "middle")}
    lo, hi = search_interval(PICKS["poly"])
    out["poly_at_ends"] = float(np.mean([r["x"]["poly"] in (lo, hi) for r in results]))
    return out


def table(summary: dict, score: str) -> str:
    def f(v):
        return "-" if v is None else f"{v:.4f}"
    rows = ["| method | mean | median | IQR | paper mean | paper median | paper IQR | median abs(x - x*) |",
            "|---|---|---|---|---|---|---|---|"]
    label = {"dense": f"dense argmin (N={DENSE_CANDIDATES})", "poly": "polynomial (N=5)", "argmin": "argmin (N=5)",
             "middle": "middle (x=0.5)", "boundary": "true crossing (x=x*)", "random": "random 3DGS split",
             "parent": "parent, unsplit"}
    for m in METHODS:
        s, p = summary[score][m], PAPER.get(m, (None, None, None))
        xe = summary["x_error"].get(m)
        rows.append(f"| {label[m]} | {s['mean']:.4f} | {s['median']:.4f} | {s['iqr']:.4f} | "
                    f"{f(p[0])} | {f(p[1])} | {f(p[2])} | {f(xe)} |")
    w = summary[score]["poly_vs_argmin"]
    rows.append(f"\npoly vs argmin, case by case: {w['wins']} wins, {w['losses']} losses, {w['ties']} ties; "
                f"poly at an end of its interval in {100 * summary['poly_at_ends']:.1f}% of cases")
    return "\n".join(rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--gt", choices=("gaussians", "regions"), default="gaussians")
    ap.add_argument("--loss", choices=("l2", "train"), default="l2")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", help="write the summary and every case's positions and scores here")
    args = ap.parse_args(argv)
    start = time.perf_counter()
    work = partial(run_case, seed=args.seed, size=args.size, gt=args.gt, loss=args.loss)
    if args.jobs > 1:
        pool = Pool(args.jobs)
        try:
            results = pool.map(work, range(args.cases), chunksize=50)
        finally:        # close and join: terminate() would SIGTERM the workers
            pool.close()
            pool.join()
    else:
        results = [work(i) for i in range(args.cases)]
    summary = summarise(results)
    elapsed = time.perf_counter() - start
    print(f"{args.cases} cases, seed {args.seed}, {args.size}x{args.size}, ground truth {args.gt}, loss {args.loss}, "
          f"{args.jobs} jobs: {elapsed:.1f} s\n")
    for score, what in (("image", "SSIM over the whole image"), ("footprint", "SSIM over the parent's footprint")):
        print(f"{what}\n\n{table(summary, score)}\n")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"args": vars(args), "seconds": elapsed, "summary": summary, "cases": results}, fh)


if __name__ == "__main__":
    main()
