"""Float64 reference of kernels/isect.cl + the two sorts: each tile's Gaussians, front to back."""
from __future__ import annotations

import numpy as np

from .project import pair_rect_reference, tile_rect_reference


def intersect_reference(mean2d, radius, alpha_extent, tiles_touched, depth, tiles_x: int, tiles_y: int,
                        alpha_cut: bool = True):
    """-> (tile_of_pair [P], gaussian_of_pair [P], ranges [tiles, 2]); pairs ordered by (tile, depth,
    Gaussian index), the order the two stable sorts produce. alpha_cut=False pairs every visible
    Gaussian with all tiles of its 3-sigma box (the Inria rule), to show that the cut changes no pixel."""
    if alpha_cut:
        vis = np.flatnonzero(np.asarray(tiles_touched) > 0)
        rect = pair_rect_reference(np.asarray(mean2d)[vis], np.asarray(radius)[vis], np.asarray(alpha_extent)[vis],
                                   tiles_x, tiles_y)
    else:
        vis = np.flatnonzero(np.asarray(radius) > 0)
        r = np.asarray(radius, np.float64)[vis, None]
        rect = tile_rect_reference(np.asarray(mean2d, np.float64)[vis], np.repeat(r, 2, 1), tiles_x, tiles_y)
    tiles, gauss = [], []
    for g, (x0, y0, x1, y1) in zip(vis, rect):
        ty, tx = np.mgrid[y0:y1, x0:x1]
        tiles.append((ty * tiles_x + tx).ravel())
        gauss.append(np.full(tiles[-1].size, g))
    tile_of_pair = np.concatenate(tiles) if tiles else np.zeros(0, np.int64)
    gaussian_of_pair = np.concatenate(gauss) if gauss else np.zeros(0, np.int64)
    order = np.lexsort((gaussian_of_pair, np.asarray(depth, np.float64)[gaussian_of_pair], tile_of_pair))
    tile_of_pair, gaussian_of_pair = tile_of_pair[order], gaussian_of_pair[order]
    n_tiles = tiles_x * tiles_y
    first = np.searchsorted(tile_of_pair, np.arange(n_tiles), "left")
    end = np.searchsorted(tile_of_pair, np.arange(n_tiles), "right")
    ranges = np.where((end > first)[:, None], np.stack([first, end], 1), 0)
    return tile_of_pair, gaussian_of_pair, ranges
