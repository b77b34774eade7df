"""Tile intersection stage (kernels/isect.cl): visible Gaussians sorted by depth, their (tile, Gaussian)
pairs emitted in that order and stably sorted by tile, and each tile's range of pairs.

The frame's counts stay on the device (StageContext.frame, constants.FRAME_WORDS) and the kernels take them from
there: the depth sort sorts every bit a depth key can have (DEPTH_KEY_BITS), where only those that differ would
need the keys' range read back first (at 8-bit digits the same passes unless the frame's depths span less than a
factor of 2^17, one pass more at most). Given a pair capacity, the host reads nothing back: the pair buffers hold
that many, and a frame with more says so on the device (the trainer runs the iteration again with room);
without one, it reads the counts once, when the pairs are counted, and sizes the buffers to fit."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..constants import FRAME_WORDS
from .project import Projected
from .scan import ExclusiveScan
from .sort import RadixSort
from .stage import Stage, StageContext
from .workspace import PAIR_SCRATCH

DEPTH_KEY_BITS = 31   # a depth key is the float bits of a depth beyond the near plane: positive, the sign bit 0
FRAME_START = np.array([0xFFFFFFFF if word == "DEPTH_KEY_MIN" else 0 for word in FRAME_WORDS], np.uint32)
FRAME = {word: i for i, word in enumerate(FRAME_WORDS)}
# A uint per pair each, dead once the pairs are gathered (in PAIR_SCRATCH): the emission arrays, the tile sort's
PAIR_TEMPORARIES = ("tile_of_emission", "emission", "gaussian_of_emission", "keys", "vals")


@dataclass
class Intersections:
    n_visible: int | None        # None where the frame was given a pair capacity (the counts stay on the device)
    n_pairs: int | None
    pair_bound: int              # C, the pairs the buffers hold: the capacity given, else n_pairs
    ranges: cl.Buffer            # [tiles*2] uint (first pair, end pair)
    gaussian_of_pair: cl.Buffer  # [C] uint, grouped by tile, front to back inside a tile
    pair_of_emission: cl.Buffer  # [C] uint: Gaussian g's pairs sit at pair_of_emission[pair_first[g] + k],
    pair_first: cl.Buffer        # [N] uint   k < tiles_touched[g] (valid where tiles_touched > 0)
    depth_bits: int              # key bits the depth sort used (DEPTH_KEY_BITS, fewer with depth_sort_bits)
    tile_bits: int               # key bits the tile sort used


class Intersect(Stage):
    FILE = "isect.cl"
    KERNELS = ("compact_visible", "emit_pairs", "gather_pairs")

    def __init__(self, ctx: StageContext):
        """ctx.options.depth_sort_bits: sort only the top this-many of the depth bits that differ (an
        approximation that trades ordering accuracy for sort passes); None sorts them all (exact)."""
        super().__init__(ctx)
        self.tuning = ctx.tuning
        self.depth_sort_bits = ctx.options.depth_sort_bits
        self.flag_scan = ExclusiveScan(ctx, flags=True)
        self.count_scan = ExclusiveScan(ctx, gather=True)
        self.sort = RadixSort(ctx)
        k = self.kernels()
        self.k_compact, self.k_emit = k["compact_visible"], k["emit_pairs"]
        self.k_gather_pairs = k["gather_pairs"]

    def defines(self) -> dict:
        return {**self.ctx.options.defines(), "ISECT_WG": self.ctx.tuning.isect_wg}

    def __call__(self, proj: Projected, tiles_x: int, tiles_y: int, pair_capacity: int | None = None) -> Intersections:
        """pair_capacity: the pairs to make room for, nothing read back (a frame with more sets the frame's
        OVERFLOWED on the device); None: the counts read back once and the buffers sized to fit."""
        rt, ws, n, frame = self.rt, self.ws, proj.n, self.ctx.frame
        wg = self.tuning.isect_wg
        tiles = tiles_x * tiles_y
        rt.write_async(frame, FRAME_START)
        visible_ids = ws.get("isect.visible_ids", 4 * n)
        depth_keys = ws.get("isect.depth_keys", 4 * n)
        if n:
            offsets = ws.get("isect.visible_offset", 4 * n)
            self.flag_scan(proj.tiles_touched, offsets, n, frame, FRAME["VISIBLE"], stage="isect")
            rt.launch_items("isect", self.k_compact, n, wg, np.uint32(n), proj.tiles_touched, offsets,
                      proj.depth, visible_ids, depth_keys, frame)
        lo, hi = 0, DEPTH_KEY_BITS
        if self.depth_sort_bits is not None:   # the top bits of those that differ: the keys' range read back first
            counts = self.ctx.frame_counts()
            kmin, kmax = counts["DEPTH_KEY_MIN"], counts["DEPTH_KEY_MAX"]
            hi = (kmin ^ kmax).bit_length() if kmin <= kmax else 0
            lo = max(0, hi - self.depth_sort_bits)
        _, ids_by_depth = self.sort(depth_keys, visible_ids, n, lo, hi, stage="sort", count=frame,
                                    count_at=FRAME["VISIBLE"])

        pair_offset = ws.get("isect.pair_offset", 4 * n)   # the visible Gaussians' first pairs, by depth
        self.count_scan(proj.tiles_touched, pair_offset, n, frame, FRAME["PAIRS"], stage="isect", count=frame,
                        count_at=FRAME["VISIBLE"], order=ids_by_depth)
        v = p = None
        if pair_capacity is None:
            counts = self.ctx.frame_counts()
            v, p = counts["VISIBLE"], counts["PAIRS"]
        c = p if pair_capacity is None else pair_capacity

        scratch = ws.scratch(PAIR_SCRATCH, {name: 4 * c for name in PAIR_TEMPORARIES})
        tile_of_emission, emission = scratch["tile_of_emission"], scratch["emission"]
        gaussian_of_emission = scratch["gaussian_of_emission"]
        pair_first = ws.get("isect.pair_first", 4 * n)
        if n:
            rt.launch_items("isect", self.k_emit, n, wg, frame, np.uint32(c), np.int32(tiles_x), np.int32(tiles_y),
                            ids_by_depth, pair_offset, proj.mean2d, proj.radius, proj.alpha_extent,
                            tile_of_emission, emission, gaussian_of_emission, pair_first)
        tile_bits = (tiles - 1).bit_length()
        tile_of_pair, emission_sorted = self.sort(tile_of_emission, emission, c, 0, tile_bits, stage="sort",
                                                  count=frame, count_at=FRAME["PAIRS"],
                                                  scratch=(scratch["keys"], scratch["vals"]))
        gaussian_of_pair = ws.get("isect.gaussian_of_pair", 4 * c)
        pair_of_emission = ws.get("isect.pair_of_emission", 4 * c)
        ranges = ws.get("isect.ranges", 8 * tiles)
        rt.fill(ranges, np.uint32(0), 8 * tiles)
        if c:
            rt.launch_items("isect", self.k_gather_pairs, c, wg, frame, np.uint32(c), emission_sorted,
                            gaussian_of_emission, tile_of_pair, gaussian_of_pair, pair_of_emission, ranges)
        return Intersections(n_visible=v, n_pairs=p, pair_bound=c, ranges=ranges, gaussian_of_pair=gaussian_of_pair,
                             pair_of_emission=pair_of_emission, pair_first=pair_first, depth_bits=hi - lo,
                             tile_bits=tile_bits)
