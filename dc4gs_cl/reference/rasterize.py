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
        d = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)[:, None, :] - mean2d[g][None]   # (pix, G, 2)
        a, b, c = conic[g, 0], conic[g, 1], conic[g, 2]
        power = -0.5 * (a * d[..., 0] ** 2 + c * d[..., 1] ** 2) - b * d[..., 0] * d[..., 1]
        alpha = np.minimum(K.ALPHA_MAX, opacity[g] * np.exp(np.minimum(power, 0)))
        blend = (power <= 0) & (alpha >= K.ALPHA_MIN)
        alpha = np.where(blend, alpha, 0.0)
        t_after = np.cumprod(1 - alpha, axis=1)
        t_before = np.concatenate([np.ones((len(d), 1)), t_after[:, :-1]], 1)
        # The first Gaussian that would push T below the limit is not blended, nor anything behind it.
        stops = blend & (t_after < K.TRANSMITTANCE_MIN)
        first_stop = np.where(stops.any(1), stops.argmax(1), len(g))
        blend &= np.arange(len(g))[None] < first_stop[:, None]
        w = np.where(blend, alpha * t_before, 0.0)
        T = np.where(first_stop < len(g), t_before[np.arange(len(d)), np.minimum(first_stop, len(g) - 1)], t_after[:, -1])
        image[ys, xs] = (w @ rgb[g] + T[:, None] * bg).reshape(ys.shape + (3,))
        final_T[ys, xs] = T.reshape(ys.shape)
        last = np.where(blend.any(1), len(g) - 1 - np.argmax(blend[:, ::-1], axis=1), -1)
        last_pair[ys, xs] = (first + last).reshape(ys.shape)
    return {"image": image, "final_T": final_T, "last_pair": last_pair}


def render_reference(means, log_scales, quats, opacity_logits, sh, cam: Camera, sh_degree: int, background,
                     alpha_cut: bool = True):
    """Project, intersect and rasterize entirely in float64 (alpha_cut: see intersect_reference)."""
    tiles_x, tiles_y = -(-cam.width // K.TILE_SIZE), -(-cam.height // K.TILE_SIZE)
    p = project_reference(means, log_scales, quats, opacity_logits, sh, cam, sh_degree, tiles_x, tiles_y)
    _, gaussian_of_pair, ranges = intersect_reference(p["mean2d"], p["radius"], p["alpha_extent"], p["tiles_touched"],
                                                      p["depth"], tiles_x, tiles_y, alpha_cut)
    out = rasterize_reference(p["mean2d"], p["conic"], p["opacity"], p["rgb"], gaussian_of_pair, ranges,
                              cam.width, cam.height, tiles_x, background)
    out["projected"] = p
    return out
