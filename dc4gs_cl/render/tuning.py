"""Work shapes per device kind: chosen by measurement on PoCL (CPU) and by the CUDA rasterizers' shapes
for GPUs. Every kernel variant exists in both shapes, so the tests run both on PoCL."""
from __future__ import annotations

from dataclasses import dataclass, replace

from ..constants import TILE_SIZE
from ..runtime import Capabilities

# CPU implementations whose compiler wants the split sums added per column block (Tuning.split_sums_per_block).
SPLIT_SUMS_PER_BLOCK = ("intel(r) opencl",)
DEAL_TILES_CPU = 16   # stripes of tiles dealt to consecutive work-groups on CPUs (Tuning.deal_tiles)


@dataclass(frozen=True)
class Tuning:
    pixels_per_item: int    # rasterizer: pixels one work-item owns (1 .. 256)
    batch: int              # rasterizer: Gaussians loaded into local memory at a time
    radix_bits: int         # sort: widest digit per pass
    sort_blocks: int        # sort: contiguous runs of keys (at most), one work-item each, or one work-group each
    scan_wg: int            # scan: work-group size
    scan_groups: int        # scan: work-groups (upper bound)
    isect_wg: int           # compaction: work-group size
    # rasterizer backward of a frame walked in runs: consecutive work-groups take tiles about tiles / deal_tiles
    # apart (rasterize_backward.cl tile_of_group), so that a CPU runtime's chunks of consecutive groups each hold
    # some of a run's consecutive tiles: PoCL dealt a run's few hundred tiles to one core (a million random
    # Gaussians at 1280x720, AbsGS + DC4GS in 9 runs: ~160 ms a run, whatever its pairs; 1,048 -> 612 ms in all).
    # Not where the whole image is busy (the forward, a frame in one run: 2-5% slower dealt, neighbouring tiles
    # sharing Gaussians in the cache); 1 on GPUs
    deal_tiles: int = 1
    # sort: 1, each run walked in sequence by a work-item (CPUs); else the work-group size that walks a run in tiles,
    # ranking each tile's keys in local memory (GPUs: coalesced loads and stores, 8-bit digits without a ballot)
    sort_wg: int = 1
    pair_sums: bool = True  # backward: per-pair slots summed per Gaussian (deterministic) instead of float atomics
    # backward with pair_sums: the slots held at once, in pairs per Gaussian; None: as many as the frame's pair
    # temporaries hold, whose room the slots take over (rasterize_backward.pair_runs), so that they add nothing to
    # the peak (1.0 before: a million random Gaussians at 1280x720, 3DGS, 6 runs -> 3 and 44 -> 37 launches per
    # iteration, gsplat's garden 4 -> 3 and 39 -> 37, the peak bytes the same). A frame with room for more pairs is
    # walked in runs of consecutive pairs, each run's slots summed before the next, at most one run per
    # min_run_tiles tiles: a launch ends with cores idle behind its slowest tiles (PoCL, 48k Gaussians: 2 runs of
    # ~54 tiles at 192x144 cost +20% of the backward; 4 runs of 90-476 tiles at 576x432, +1%)
    pair_chunk: float | None = None
    min_run_tiles: int = 256
    # backward with a densification window: sum_pairs folds the view into it (only Gaussians spanning runs keep sums
    # between runs) in frames walked in at most this many runs; past that the full per-Gaussian sums and the
    # window's own kernel, as the fold (vectorised past a barrier) runs masked for every Gaussian a run's launch
    # covers, and carries more sums between more runs (PoCL, AbsGS + DC4GS: 400k Gaussians at 576x432 in 3 runs,
    # sum_pairs as fast and 1,480 -> 1,369 bytes per Gaussian; a million at 1280x720 in 5 runs, sum_pairs and
    # densify_stats 376 + 23 -> 473 ms for 1,502 -> 1,400 bytes per Gaussian). 4, not 3, since the runs cover the
    # trainer's pair room (1.125x the pairs), which adds a run to frames such as gsplat's garden (3 runs -> 4)
    max_folded_runs: int = 4
    # backward with DC4GS' split sums: a column block's 25 split terms added after its pixels' walk, in explicit
    # vector adds, instead of inside the walk (exact: the same adds in the same order). Intel's CPU runtime
    # compiles the walk with them inside 7x slower than without (AVX2, 48k Gaussians, 192x144: 99.8 against 14.4
    # ms), per block 26.8; PoCL vectorises the walk either way and is faster with them inside (38.8 against 59.7).
    split_sums_per_block: bool = False
    # rasterizer backward in the GPU shape (a pixel per item): how subgroups of 32 items reduce a pair's sums
    # (runtime.SUBGROUP_SOURCES); None: 32 pixels per item, summed in the same order (the portable twin)
    subgroups: str | None = None

    @staticmethod
    def for_device(caps: Capabilities) -> "Tuning":
        if caps.is_cpu and not caps.loop_limit:
            # One work-item per tile vectorises across the tile's pixels; sequential runs for the
            # sort and scan keep each core streaming through memory.
            cores = max(1, caps.compute_units)
            per_block = any(name in caps.platform.lower() for name in SPLIT_SUMS_PER_BLOCK)
            return Tuning(pixels_per_item=256, batch=32, radix_bits=8, sort_blocks=4 * cores,
                          scan_wg=1, scan_groups=4 * cores, isect_wg=64, deal_tiles=DEAL_TILES_CPU,
                          split_sums_per_block=per_block).within(caps)
        # GPUs, and drivers that cut a work-item's loops short (Capabilities.loop_limit): one pixel, and short
        # runs of keys and of scan elements, per work-item.
        return Tuning(pixels_per_item=1, batch=256, radix_bits=8, sort_blocks=512, sort_wg=256,
                      scan_wg=256, scan_groups=256, isect_wg=256, subgroups=caps.subgroups).within(caps)

    def within(self, caps: Capabilities) -> "Tuning":
        """This shape narrowed to the device's work-group limit: a tile's items (TILE_SIZE^2 / pixels_per_item),
        the sort's, the scan's and the compaction's work-groups. (Local memory: the stages that hold arrays there fit
        their own, Loss and RasterizeBackward.)"""
        limit = max(1, caps.max_work_group_size)
        ppi = self.pixels_per_item
        while TILE_SIZE * TILE_SIZE // ppi > limit:
            ppi *= 2          # 1, 2, 4, 8, then whole rows (16, 32, ...): the values raster.h takes
        return replace(self, pixels_per_item=ppi, sort_wg=_power_of_two_within(self.sort_wg, limit),
                       scan_wg=_power_of_two_within(self.scan_wg, limit),
                       isect_wg=_power_of_two_within(self.isect_wg, limit))


def _power_of_two_within(size: int, limit: int) -> int:
    while size > limit:
        size //= 2
    return size
