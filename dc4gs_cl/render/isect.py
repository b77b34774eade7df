"""Tile intersection stage (kernels/isect.cl): visible Gaussians sorted by depth, their (tile, Gaussian)
pairs emitted in that order and stably sorted by tile, and each tile's range of pairs."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from .project import Projected
from .scan import ExclusiveScan
from .sort import RadixSort
from .stage import Stage, StageContext


@dataclass
class Intersections:
    n_visible: int
    n_pairs: int
    ranges: cl.Buffer            # [tiles*2] uint (first pair, end pair)
    gaussian_of_pair: cl.Buffer  # [P] uint, grouped by tile, front to back inside a tile
    tile_of_pair: cl.Buffer      # [P] uint
    pair_of_emission: cl.Buffer  # [P] uint: Gaussian g's pairs sit at pair_of_emission[pair_first[g] + k],
    pair_first: cl.Buffer        # [N] uint   k < tiles_touched[g] (valid where tiles_touched > 0)
    depth_bits: int              # key bits the depth sort used
    tile_bits: int               # key bits the tile sort used


class Intersect(Stage):
    FILE = "isect.cl"
    KERNELS = ("compact_visible", "gather_tile_counts", "emit_pairs", "gather_pairs", "tile_ranges")

    def __init__(self, ctx: StageContext):
        """ctx.options.depth_sort_bits: sort only the top this-many of the depth bits that differ (an
        approximation that trades ordering accuracy for sort passes); None sorts them all (exact)."""
        super().__init__(ctx)
        self.tuning = ctx.tuning
        self.depth_sort_bits = ctx.options.depth_sort_bits
        self.flag_scan = ExclusiveScan(ctx, flags=True)
        self.count_scan = ExclusiveScan(ctx)
        self.sort = RadixSort(ctx)
        k = self.kernels()
        self.k_compact, self.k_gather, self.k_emit = k["compact_visible"], k["gather_tile_counts"], k["emit_pairs"]
        self.k_gather_pairs, self.k_ranges = k["gather_pairs"], k["tile_ranges"]
        self.counters = self.rt.buffer(16)   # visible count, depth key min, depth key max, pair count

    def defines(self) -> dict:
        return {**self.ctx.options.defines(), "ISECT_WG": self.ctx.tuning.isect_wg}

    def __call__(self, proj: Projected, tiles_x: int, tiles_y: int) -> Intersections:
        rt, ws, n = self.rt, self.ws, proj.n
        wg = self.tuning.isect_wg
        tiles = tiles_x * tiles_y
        counters = np.array([0, 0xFFFFFFFF, 0, 0], np.uint32)
        rt.write(self.counters, counters)
        visible_ids = ws.get("isect.visible_ids", 4 * n)
        depth_keys = ws.get("isect.depth_keys", 4 * n)
        if n:
            offsets = ws.get("isect.visible_offset", 4 * n)
            self.flag_scan(proj.tiles_touched, offsets, n, self.counters, 0, stage="isect")
            rt.launch_items("isect", self.k_compact, n, wg, np.uint32(n), proj.tiles_touched, offsets,
                      proj.depth, visible_ids, depth_keys, self.counters)
            cl.enqueue_copy(rt.queue, counters, self.counters)
        v, kmin, kmax = int(counters[0]), int(counters[1]), int(counters[2])

        depth_bits = (kmin ^ kmax).bit_length() if v > 1 else 0
        lo = 0 if self.depth_sort_bits is None else max(0, depth_bits - self.depth_sort_bits)
        _, ids_by_depth = self.sort(depth_keys, visible_ids, v, lo, depth_bits, stage="sort")

        pair_offset = ws.get("isect.pair_offset", 4 * v)
        if v:
            rt.launch_items("isect", self.k_gather, v, wg, np.uint32(v), ids_by_depth,
                      proj.tiles_touched, pair_offset)
        self.count_scan(pair_offset, pair_offset, v, self.counters, 3, stage="isect")
        cl.enqueue_copy(rt.queue, counters, self.counters)
        p = int(counters[3])

        tile_of_emission = ws.get("isect.tile_of_emission", 4 * p)
        emission = ws.get("isect.emission", 4 * p)
        gaussian_of_emission = ws.get("isect.gaussian_of_emission", 4 * p)
        pair_first = ws.get("isect.pair_first", 4 * n)
        if v:
            rt.launch_items("isect", self.k_emit, v, wg, np.uint32(v), np.int32(tiles_x),
                      np.int32(tiles_y), ids_by_depth, pair_offset, proj.mean2d, proj.radius, proj.alpha_extent,
                      tile_of_emission, emission, gaussian_of_emission, pair_first)
        tile_bits = (tiles - 1).bit_length()
        tile_of_pair, emission_sorted = self.sort(tile_of_emission, emission, p, 0, tile_bits, stage="sort")
        gaussian_of_pair = ws.get("isect.gaussian_of_pair", 4 * p)
        pair_of_emission = ws.get("isect.pair_of_emission", 4 * p)
        if p:
            rt.launch_items("isect", self.k_gather_pairs, p, wg, np.uint32(p), emission_sorted,
                      gaussian_of_emission, gaussian_of_pair, pair_of_emission)

        ranges = ws.get("isect.ranges", 8 * tiles)
        rt.fill(ranges, np.uint32(0), 8 * tiles)
        if p:
            rt.launch_items("isect", self.k_ranges, p, wg, np.uint32(p), tile_of_pair, ranges)
        return Intersections(n_visible=v, n_pairs=p, ranges=ranges, gaussian_of_pair=gaussian_of_pair,
                             tile_of_pair=tile_of_pair, pair_of_emission=pair_of_emission, pair_first=pair_first,
                             depth_bits=depth_bits - lo, tile_bits=tile_bits)
