"""Float64 reference of kernels/rasterize.cl, and a whole-image reference renderer."""
from __future__ import annotations

import numpy as np

from .. import constants as K
from ..scene.camera import Camera
from .isect import intersect_reference
from .project import project_reference


def rasterize_reference(mean2d, conic, opacity, rgb, gaussian_of_pair, ranges, width: int, height: int,
                        tiles_x: int, background) -> dict[str, np.ndarray]:
    """Front-to-back alpha blending per pixel (pixel centres at +0.5). Returns image (H, W, 3),
    final_T (H, W) and last_pair (H, W): the pair index of the last blended Gaussian (first - 1 if none)."""
    image = np.zeros((height, width, 3))
    final_T = np.ones((height, width))
    last_pair = np.zeros((height, width), np.int64)
    bg = np.asarray(background, np.float64)
    for tile, (first, end) in enumerate(np.asarray(ranges)):
        y0, x0 = (tile // tiles_x) * K.TILE_SIZE, (tile % tiles_x) * K.TILE_SIZE
        ys, xs = np.mgrid[y0:min(y0 + K.TILE_SIZE, height), x0:min(x0 + K.TILE_SIZE, width)]
        if ys.size == 0:
            continue
        last_pair[ys, xs] = first - 1
        image[ys, xs] = bg
        if end <= first:
            continue
        g = np.asarray(gaussian_of_pair[first:end])
        _, _, _, alpha, blend, t_before = _tile_blend(mean2d, conic, opacity, g, xs, ys)
        w = alpha * t_before
        T = 1 - w.sum(1)   # the product of (1 - alpha) over blended Gaussians
        image[ys, xs] = (w @ rgb[g] + T[:, None] * bg).reshape(ys.shape + (3,))
        final_T[ys, xs] = T.reshape(ys.shape)
        last = np.where(blend.any(1), len(g) - 1 - np.argmax(blend[:, ::-1], axis=1), -1)
        last_pair[ys, xs] = (first + last).reshape(ys.shape)
    return {"image": image, "final_T": final_T, "last_pair": last_pair}


def render_reference(means, log_scales, quats, opacity_logits, sh, cam: Camera, sh_degree: int, background,
                     alpha_cut: bool = True):
    """Project, intersect and rasterize entirely in float64 (alpha_cut: see intersect_reference)."""
    tiles_x, tiles_y = K.tile_grid(cam.width, cam.height)
    p = project_reference(means, log_scales, quats, opacity_logits, sh, cam, sh_degree, tiles_x, tiles_y)
    _, gaussian_of_pair, ranges = intersect_reference(p["mean2d"], p["radius"], p["alpha_extent"], p["tiles_touched"],
                                                      p["depth"], tiles_x, tiles_y, alpha_cut)
    out = rasterize_reference(p["mean2d"], p["conic"], p["opacity"], p["rgb"], gaussian_of_pair, ranges,
                              cam.width, cam.height, tiles_x, background)
    out["projected"] = p
    return out


def _tile_blend(mean2d, conic, opacity, g, xs, ys):
    """Per (pixel, Gaussian) quantities of one tile's front-to-back list g, as rasterize_reference
    computes them: offsets, Gaussian value, alpha, blend mask and T before each Gaussian."""
    d = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)[:, None, :] - mean2d[g][None]
    a, b, c = conic[g, 0], conic[g, 1], conic[g, 2]
    power = -0.5 * (a * d[..., 0] ** 2 + c * d[..., 1] ** 2) - b * d[..., 0] * d[..., 1]
    G = np.exp(np.minimum(power, 0))
    oG = opacity[g] * G
    alpha = np.minimum(K.ALPHA_MAX, oG)
    blend = (power <= 0) & (alpha >= K.ALPHA_MIN)
    alpha = np.where(blend, alpha, 0.0)
    t_after = np.cumprod(1 - alpha, axis=1)
    t_before = np.concatenate([np.ones((len(d), 1)), t_after[:, :-1]], 1)
    stops = blend & (t_after < K.TRANSMITTANCE_MIN)
    first_stop = np.where(stops.any(1), stops.argmax(1), len(g))
    blend &= np.arange(len(g))[None] < first_stop[:, None]
    alpha = np.where(blend, alpha, 0.0)
    return d, G, oG, alpha, blend, t_before


def rasterize_backward_reference(mean2d, conic, opacity, rgb, gaussian_of_pair, ranges, width: int, height: int,
                                 tiles_x: int, background, dL_dimage, split=None, keep=None,
                                 near_px: float = 1e-2) -> dict[str, np.ndarray]:
    """Gradients of sum(image * dL_dimage) with respect to the rasterizer's per-Gaussian inputs, and the
    densification statistics, in closed form per tile (reverse cumulative sums over each tile's list):
        mean2d (N, 2) px, conic (N, 3), opacity (N,), rgb (N, 3);
        abs (N, 2): sum over pixels of |g_x|, |g_y| with g = pixel's dL/dmean2d in NDC units (x W/2, H/2);
        pixels (N,): pixels where blended; dc (N, 3): sum of g/|g| over pixels with |g| > 0, and their count;
        with split = (candidate pixels (N, C, 2), end pixels (N, 2), valid (N,)) from
        dc4gs.split_geometry_reference: split (N, C, 5), for each candidate the sums (u_x, u_y, count,
        |g_x|, |g_y|) over the pixels with |g| > 0 on its left, decided as the paper's algorithm 3 does:
        left when (end - candidate) . (pixel - candidate) < 0; and split_near (N, C, 5): the same sums of the
        values' magnitudes over the pixels within near_px of the candidate's line, whose side float32 geometry
        may decide the other way (what a float32 kernel's left sums may differ by, past rounding).
    keep (H, W) bool: a mask; the pixels it masks out take no part (no gradient, no statistic).
    No gradient flows through alpha where min(ALPHA_MAX, o G) clamps."""
    n = len(mean2d)
    out = {"mean2d": np.zeros((n, 2)), "conic": np.zeros((n, 3)), "opacity": np.zeros(n), "rgb": np.zeros((n, 3)),
           "abs": np.zeros((n, 2)), "pixels": np.zeros(n), "dc": np.zeros((n, 3))}
    if split is not None:
        cand_px, end_px, split_valid = split
        out["split"] = np.zeros((n, cand_px.shape[1], 5))
        out["split_near"] = np.zeros((n, cand_px.shape[1], 5))
    bg = np.asarray(background, np.float64)
    ndc = np.array([0.5 * width, 0.5 * height])
    for tile, (first, end) in enumerate(np.asarray(ranges)):
        if end <= first:
            continue
        y0, x0 = (tile // tiles_x) * K.TILE_SIZE, (tile % tiles_x) * K.TILE_SIZE
        ys, xs = np.mgrid[y0:min(y0 + K.TILE_SIZE, height), x0:min(x0 + K.TILE_SIZE, width)]
        if keep is not None:
            kept = keep[ys, xs]
            ys, xs = ys[kept], xs[kept]
        if ys.size == 0:
            continue
        g = np.asarray(gaussian_of_pair[first:end])
        d, G, oG, alpha, blend, t_before = _tile_blend(mean2d, conic, opacity, g, xs, ys)
        dLdC = np.asarray(dL_dimage, np.float64)[ys.ravel(), xs.ravel()]               # (pix, 3)
        w = alpha * t_before                                                           # (pix, G)
        wc = w[..., None] * rgb[g][None]                                               # (pix, G, 3)
        behind = wc[:, ::-1].cumsum(1)[:, ::-1] - wc                                   # sum over m > k
        t_final = 1 - w.sum(1)   # = prod(1 - alpha) over blended Gaussians
        dC_dalpha = (t_before[..., None] * rgb[g][None]
                     - (behind + (t_final[:, None, None] * bg)) / (1 - alpha)[..., None])
        dL_dalpha = np.where(blend, np.einsum("pgc,pc->pg", dC_dalpha, dLdC), 0.0)
        live = blend & (oG < K.ALPHA_MAX)
        dL_dG = np.where(live, opacity[g] * dL_dalpha, 0.0)
        gG = dL_dG * G
        a, b, c = conic[g, 0], conic[g, 1], conic[g, 2]
        dx, dy = d[..., 0], d[..., 1]
        gm = np.stack([gG * (a * dx + b * dy), gG * (c * dy + b * dx)], -1)          # (pix, G, 2)
        np.add.at(out["mean2d"], g, gm.sum(0))
        np.add.at(out["conic"], g, np.stack([-0.5 * gG * dx * dx, -gG * dx * dy, -0.5 * gG * dy * dy], -1).sum(0))
        np.add.at(out["opacity"], g, np.where(live, G * dL_dalpha, 0.0).sum(0))
        np.add.at(out["rgb"], g, np.einsum("pg,pc->gc", w, dLdC))
        gn = gm * ndc
        norm = np.linalg.norm(gn, axis=-1)
        unit = np.where(norm[..., None] > 0, gn / np.where(norm > 0, norm, 1)[..., None], 0.0)
        np.add.at(out["abs"], g, np.abs(gn).sum(0))
        np.add.at(out["pixels"], g, blend.sum(0))
        np.add.at(out["dc"], g, np.concatenate([unit, (norm > 0)[..., None]], -1).sum(0))
        if split is not None:
            q = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)                      # (pix, 2)
            values = np.concatenate([unit, (norm > 0)[..., None], np.abs(gn)], -1)      # (pix, G, 5)
            values *= ((norm > 0) & split_valid[g][None])[..., None]
            cand, end = cand_px[g], end_px[g]                                           # (G, C, 2), (G, 2)
            side = np.einsum("gci,pgci->pgc", end[:, None] - cand, q[:, None, None] - cand[None])
            np.add.at(out["split"], g, np.einsum("pgc,pgv->gcv", (side < 0).astype(float), values))
            near = np.abs(side) <= near_px * np.linalg.norm(end[:, None] - cand, axis=-1)[None]
            np.add.at(out["split_near"], g, np.einsum("pgc,pgv->gcv", near.astype(float), np.abs(values)))
    return out


def undecided_pixels(mean2d, conic, opacity, depth, gaussian_of_pair, ranges, width, height, tiles_x, margin=1e-3,
                     depth_margin=1e-6):
    """(height, width) mask of the pixels where float32 and float64 can decide a blend differently: some pair
    within a relative `margin` of the 1/255 alpha cut-off or the alpha clamp, or transmittance within it of
    the stop threshold. A flipped decision there moves whole pixels' worth of gradient, not rounding. So does a
    flipped order: the pixels that two Gaussians next in a tile's list and within a relative `depth_margin` in
    depth (about 8 float32 ulps) may both blend, as float32 may sort them the other way."""
    out = np.zeros((height, width), bool)
    near = lambda x, t: np.abs(x - t) < margin * t
    for tile, (first, end) in enumerate(np.asarray(ranges)):
        y0, x0 = (tile // tiles_x) * K.TILE_SIZE, (tile % tiles_x) * K.TILE_SIZE
        ys, xs = np.mgrid[y0:min(y0 + K.TILE_SIZE, height), x0:min(x0 + K.TILE_SIZE, width)]
        if end <= first or not ys.size:
            continue
        g = gaussian_of_pair[first:end]
        _, _, oG, alpha, blend, t_before = _tile_blend(mean2d, conic, opacity, g, xs, ys)
        ambiguous = near(oG, K.ALPHA_MIN) | near(oG, K.ALPHA_MAX) | (blend & near(t_before * (1 - alpha),
                                                                                 K.TRANSMITTANCE_MIN))
        d = np.asarray(depth)[g]                     # front to back
        may_blend = oG >= K.ALPHA_MIN * (1 - margin)
        for j in np.flatnonzero(np.abs(np.diff(d)) < depth_margin * np.abs(d[1:])):
            ambiguous[:, j] |= may_blend[:, j] & may_blend[:, j + 1]
        out[ys.ravel(), xs.ravel()] = ambiguous.any(axis=1)
    return out
