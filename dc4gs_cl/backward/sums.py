"""The per-Gaussian sums the rasterizer backward writes for one view (the SUM record, kernels/
rasterize_backward.cl): the gradients project_backward reads, and, switched on by what a densification
strategy gathers (host/densify/statistics.py builds these layouts), its statistics."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..layout import Record
from .split_geometry import geometry_record

SPLIT_SUMS = 5   # per split candidate, over the pixels left of it: u_x, u_y, count, |g_x|, |g_y|


@dataclass(frozen=True)
class SumsLayout:
    """Which sums the backward gathers: the gradients always, mean2d (2, px), conic (3), opacity (1), rgb (3);
    with stats: abs (2, sum |g_x|, |g_y| in NDC units), pixels (1); with dc_stats: dc (3, sum of g/|g| and
    the count); with split_candidates N: split (SPLIT_SUMS N, the left side of each candidate; the right side
    is the total, from dc and abs, minus the left)."""
    stats: bool = False
    dc_stats: bool = False
    split_candidates: int = 0

    def __post_init__(self):
        if self.dc_stats and not self.stats:
            raise ValueError("directional-consistency statistics need the base statistics")
        if self.split_candidates and not self.dc_stats:
            raise ValueError("split costs need the directional-consistency statistics")
        if self.split_candidates and self.split_candidates % 2 == 0:
            raise ValueError("the number of split candidates must be odd")

    @cached_property
    def record(self) -> Record:
        fields = [("mean2d", 2), ("conic", 3), ("opacity", 1), ("rgb", 3)]
        if self.stats:
            fields += [("abs", 2), ("pixels", 1)]
        if self.dc_stats:
            fields += [("dc", 3)]
        if self.split_candidates:
            fields += [("split", SPLIT_SUMS * self.split_candidates)]
        return Record("SUM", fields)

    @property
    def width(self) -> int:
        return self.record.width

    def defines(self) -> dict[str, int]:
        """The record's offsets and the kernel's switches (with split sums, the split geometry's offsets)."""
        geometry = geometry_record(self.split_candidates).defines() if self.split_candidates else {}
        return {**self.record.defines(), **geometry, "STATS": int(self.stats), "DC_STATS": int(self.dc_stats),
                "SPLIT_CANDIDATES": self.split_candidates}

    def views(self, sums: np.ndarray) -> dict[str, np.ndarray]:
        """(N, width) host rows -> named views."""
        return self.record.views(sums)


GRADIENTS = SumsLayout()   # the gradients alone: what a view gathers once the densification window has closed
