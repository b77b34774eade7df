"""Rasterizer backward stage (kernels/rasterize_backward.cl): per-Gaussian sums of this view's gradients
and of the densification statistics the layout asks for (statistics.SumsLayout), folded into the window
where one is given (WindowFold: by sum_pairs, or by the window's own kernel)."""
from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np
import pyopencl as cl

from ..constants import TILE_SIZE
from ..errors import DeviceError
from ..render.isect import PAIR_TEMPORARIES
from ..render.rasterize import background_value, raster_defines
from ..render.renderer import RenderResult
from ..render.stage import Stage, visible_rows
from ..render.tuning import Tuning
from ..render.workspace import PAIR_SCRATCH
from ..runtime import SUBGROUP_SOURCES
from ..statistics import GRADIENTS, SumsLayout
from .densify_stats import DensifyStats, WindowFold
from .sum_pairs import Carry, SumPairs

# Workspace buffers (render/workspace.py)
SUMS = "backward.sums"              # [N*width] the view's per-Gaussian sums (returned)
PAIR_SUMS = "pair_sums"             # [pairs of a run * layout.width] one slot per (tile, Gaussian) pair, in
                                    # PAIR_SCRATCH: the frame's pair temporaries and the loss' are dead by then

SUBGROUP = 32             # lanes that reduce a pair's sums in the GPU shape (NVIDIA's warp)
TWIN = {"PIXELS_PER_ITEM": SUBGROUP, "COL_BLOCK": TILE_SIZE, "SUBGROUP": 0}   # its portable twin (see the kernel)
# The cooperative shapes' partial sums: PART_CHUNK pairs' worth at a time, in at most PART_BYTES of local memory
# and at most PART_CHUNK_MAX pairs (a barrier per chunk). In the GPU shape at its batch of 256 a work-group holds
# 25.6 KB for 3DGS' sums with statistics and 37.1 KB with DC4GS'. Registers, not local memory, bound the work-groups
# an NVIDIA multiprocessor holds (tools/ptx_occupancy.py, clang + ptxas for sm_86): 56 per item for AbsGS, 71 for
# AbsGS + DC4GS, 4 and 3 work-groups of 256 (91 and 255 with 600 bytes spilled before the split sums were reduced
# candidate by candidate after the walk and the reduction held no select between two of its array's elements: 2, 1).
PART_BYTES, PART_CHUNK_MAX = 16 * 1024, 32


class RasterizeBackward(Stage):
    FILE, KERNELS = "rasterize_backward.cl", ("rasterize_backward",)

    def __init__(self, ctx):
        super().__init__(ctx)
        self.sum_pairs = SumPairs(ctx)
        self.densify_stats = DensifyStats(ctx)
        # the GPU shape's subgroup source, until a variant fails to build with it (then the twin)
        self.subgroups = ctx.tuning.subgroups if ctx.tuning.pixels_per_item == 1 else None
        self._fitted: dict[tuple, dict[str, cl.Kernel]] = {}

    def fitted_kernels(self, variant: dict) -> dict[str, cl.Kernel]:
        """A variant's kernels whose local arrays (a batch of Gaussians, their split geometry and, in the
        cooperative shapes, the partial sums) fit the device; the twin's where the subgroup path fails to build.
        Built and checked once per variant."""
        key = tuple(sorted(variant.items()))
        if key not in self._fitted:
            self._fitted[key] = self._fit(variant)
        return self._fitted[key]

    def _fit(self, variant: dict) -> dict[str, cl.Kernel]:
        try:
            kernels = self.batch_fitted_kernels({**variant, **self.shape(variant)}, "rasterize_backward")
            if self.subgroups == "khr":   # the device's subgroups (or the size it grants) must hold whole 32s
                try:
                    size = kernels["rasterize_backward"].get_sub_group_info(
                        self.rt.device, cl.kernel_sub_group_info.MAX_SUB_GROUP_SIZE_FOR_NDRANGE,
                        [TILE_SIZE * TILE_SIZE])
                except cl.Error as e:   # an OpenCL 2.0 device may not answer (the query is 2.1's)
                    raise DeviceError(f"its subgroup size is not known ({e})") from None
                if size % SUBGROUP:
                    raise DeviceError(f"subgroups of {size} work-items, not a multiple of {SUBGROUP}")
            return kernels
        except DeviceError as e:
            if self.subgroups is None:
                raise
            first_error = next((line for line in str(e).splitlines() if "error" in line), str(e).splitlines()[0])
            warnings.warn(f"the rasterizer backward's {self.subgroups} subgroup path did not build on this device; "
                          f"using its portable twin (the same sums, slower): {first_error.strip()}")
            self.subgroups = None
            self._fitted.clear()   # every variant takes the twin's shape from now on
            return self.batch_fitted_kernels({**variant, **self.shape(variant)}, "rasterize_backward")

    def shape(self, variant: dict) -> dict:
        """The work shape: the rasterizer's, except that the GPU shape (a pixel per item) reduces a pair's sums over
        subgroups of SUBGROUP items, or, where the device has none, takes SUBGROUP pixels per item (the twin);
        PART_CHUNK: the pairs whose partial sums the cooperative shapes hold at once."""
        tuning = self.ctx.tuning
        shape = {"SUBGROUP": 0}
        if tuning.pixels_per_item == 1:
            sources = {f"SUBGROUP_{name.upper()}": value for name, value in SUBGROUP_SOURCES.items()}
            shape = ({"SUBGROUP": SUBGROUP, "SUBGROUP_SOURCE": SUBGROUP_SOURCES[self.subgroups], **sources}
                     if self.subgroups else TWIN)
        items = self.items(shape)
        owners = items // (shape["SUBGROUP"] or 1)   # partial rows per pair
        fitting = PART_BYTES // (4 * owners * variant["SUM_WIDTH"])
        return {**shape, "PART_CHUNK": tuning.batch if items == 1 else max(1, min(PART_CHUNK_MAX, fitting))}

    def with_batch(self, variant: dict, batch: int) -> dict:
        return {"PART_CHUNK": min(variant["PART_CHUNK"], batch)}

    def items(self, shape: dict) -> int:
        """Work-items per tile."""
        return TILE_SIZE * TILE_SIZE // shape.get("PIXELS_PER_ITEM", self.ctx.tuning.pixels_per_item)

    def language(self, variant: dict) -> str:
        return "CL3.0" if variant.get("SUBGROUP_SOURCE") == SUBGROUP_SOURCES["khr"] else "CL1.2"

    def defines(self) -> dict:
        # pair_sums: one slot per (tile, Gaussian) pair, summed per Gaussian in a fixed order (deterministic);
        # otherwise float atomics into the per-Gaussian sums (--low-memory).
        return {**raster_defines(self.ctx), "PAIR_SUMS": int(self.ctx.tuning.pair_sums),
                "SPLIT_SUMS_PER_BLOCK": int(self.ctx.tuning.split_sums_per_block), "DEAL_TILES": 1}

    def __call__(self, res: RenderResult, dL_dimage: cl.Buffer, background, layout: SumsLayout,
                 geometry: cl.Buffer | None = None, keep: cl.Buffer | None = None) -> cl.Buffer:
        """Per-Gaussian sums (N x layout.width floats); split sums need the view's split geometry. keep: the
        view's mask (H x W uint8, 0 = masked out), whose masked pixels add nothing."""
        return self.folding(res, dL_dimage, background, layout, geometry, keep)[0]

    def plan(self, res: RenderResult, layout: SumsLayout, window: WindowFold | None = None,
             carry_rows: int | None = None) -> RunPlan:
        """How the view's pairs will be walked (pair_runs) and, walked in runs with the window folded by sum_pairs,
        its carry: with carry_rows rows, a view with more Gaussians spanning runs void on the device (the trainer
        queues this before anything that changes lasting state, and runs the view again with more); None: as many
        as it has, read back."""
        tuning, n = self.ctx.tuning, res.proj.n
        runs, per_run = pair_runs(res.isect.pair_bound, n, res.tiles_x * res.tiles_y, tuning, layout.width)
        fused = window is not None and tuning.pair_sums and runs <= tuning.max_folded_runs
        rows = 0
        if runs > 1 and n:
            self.sum_pairs.run_spans(res, layout, window if fused else None, per_run, runs,
                                     carry_rows if fused else None)
            if fused:
                rows = self.ctx.frame_counts()["SPANNING"] if carry_rows is None else carry_rows
        return RunPlan(runs, per_run, fused, self.sum_pairs.carry(layout, n, rows) if fused else None)

    def folding(self, res: RenderResult, dL_dimage: cl.Buffer, background, layout: SumsLayout,
                geometry: cl.Buffer | None = None, keep: cl.Buffer | None = None,
                window: WindowFold | None = None, plan: RunPlan | None = None) -> tuple[cl.Buffer, SumsLayout]:
        """As a call, and with a window (layout with statistics), the view's statistics folded into it: by
        sum_pairs as it adds up each Gaussian's slots (the sums returned then hold the gradients alone, and the
        per-Gaussian statistics never reach memory: 124 of 160 bytes per Gaussian with DC4GS; in a few runs,
        Tuning.max_folded_runs, only the Gaussians whose pairs span runs hold theirs between runs, in carry rows),
        else (float atomics, or more runs) by the window's own kernel. plan: the view's (self.plan, with this
        layout and window), made here where not given. The sums and their layout."""
        if layout.split_candidates and geometry is None:
            raise ValueError("split costs need the split geometry of the view")
        rt, tuning = self.rt, self.ctx.tuning
        n, bound, tiles = res.proj.n, res.isect.pair_bound, res.tiles_x * res.tiles_y
        plan = plan or self.plan(res, layout, window)
        out_layout = GRADIENTS if plan.fused else layout
        sums = self.ws.get(SUMS, 4 * out_layout.width * max(n, 1))
        if tuning.pair_sums:
            target = self.ws.scratch(PAIR_SCRATCH, {PAIR_SUMS: 4 * layout.width * plan.pairs_per_run})[PAIR_SUMS]
        else:
            target = sums
            rt.fill(sums, np.float32(0), 4 * layout.width * n)
        fold = window if plan.fused else None
        # a run's tiles are consecutive: dealt in stripes, as CPU runtimes deal each core consecutive groups
        variant = {**layout.defines(), "PIXEL_MASK": int(keep is not None),
                   "DEAL_TILES": tuning.deal_tiles if plan.runs > 1 else 1}
        k = self.fitted_kernels(variant)
        items = self.items(self.shape(variant))
        split_geometry = geometry if geometry is not None else sums
        for run in range(plan.runs):
            p0, p1 = run * plan.pairs_per_run, min(bound, (run + 1) * plan.pairs_per_run)
            rt.launch("rasterize_backward", k["rasterize_backward"], tiles * items, items,
                      np.int32(res.width), np.int32(res.height), np.int32(res.tiles_x), np.uint32(p0), np.uint32(p1),
                      background_value(background), res.isect.ranges, res.isect.gaussian_of_pair, res.proj.mean2d,
                      res.proj.conic_opacity, res.proj.rgb, res.proj.alpha_extent, res.raster.final_T,
                      res.raster.last_pair, dL_dimage, split_geometry, *([keep] if keep is not None else []), target)
            if tuning.pair_sums:
                self.sum_pairs(res, layout, target, p0, p1, run, plan.runs, split_geometry, sums, fold, plan.carry)
        self.check(lambda: {"sums": visible_rows(rt, sums, rt.to_host(res.proj.radius, n, np.int32),
                                                 out_layout.width)})
        if window is not None and not plan.fused:
            self.densify_stats(res, sums, geometry, window)
        return sums, out_layout


class RunPlan(NamedTuple):
    """How a view's backward walks its pairs: in `runs` runs of pairs_per_run consecutive pairs (pair_runs),
    its statistics folded by sum_pairs (fused) with this carry (runs > 1), or not."""
    runs: int
    pairs_per_run: int
    fused: bool
    carry: Carry | None


def pair_runs(bound: int, n: int, tiles: int, tuning: Tuning, width: int) -> tuple[int, int]:
    """The runs of consecutive pairs a view with room for `bound` pairs is walked in, and the pairs per run, for
    slots of `width` sums: one run unless the pairs outnumber the slots held at once in a frame of at least
    2 min_run_tiles tiles, and at most one run per min_run_tiles tiles (a launch ends with cores idle behind its
    slowest tiles). The slots held at once: as many as the frame's pair temporaries (PAIR_SCRATCH, whose room the
    slots take over) hold, so that even wide slots (DC4GS' 40 sums) add nothing to the peak; Tuning.pair_chunk per
    Gaussian where that is fewer. Fixed on the host from the bound alone, so that nothing is read back: a run past the
    view's pairs has nothing to do."""
    room = len(PAIR_TEMPORARIES) * bound // width
    budget = max(room if tuning.pair_chunk is None else min(math.ceil(tuning.pair_chunk * n), room), 1)
    if not tuning.pair_sums or bound <= budget or tiles < 2 * tuning.min_run_tiles:
        return 1, max(bound, 1)
    per_run = max(budget, -(-bound // (tiles // tuning.min_run_tiles)))
    return -(-bound // per_run), per_run
