"""--check-finite: each stage's outputs read back after it runs, and the run stopped at the first NaN or
Inf, named by stage, buffer and where in the run it happened. Off (the default) it costs nothing; on, it
waits for every stage, so it is a debugging switch, not a training mode."""
from __future__ import annotations

import numpy as np


class NonFiniteError(Exception):
    """A stage wrote NaN or Inf: the message names the stage, the buffer, the place in the run (iteration or
    view) and the first bad element."""

    def __init__(self, stage: str, buffer: str, at: str, bad: int, total: int, first: tuple):
        self.stage, self.buffer, self.at = stage, buffer, at
        where = f"{at}: " if at else ""
        super().__init__(f"{where}stage {stage} wrote {bad:,} NaN/Inf of {total:,} values in {buffer} "
                         f"(first at index {', '.join(map(str, first))})")


class FiniteCheck:
    """Shared by every stage of a pipeline (render.stage.StageContext). `at` says where the run is (set by
    the trainer or the renderer's caller) and goes into the error."""

    def __init__(self, enabled: bool = False):
        self.enabled = enabled
        self.at = ""

    def __call__(self, stage: str, arrays: dict[str, np.ndarray]) -> None:
        """Raise NonFiniteError for the first array holding a NaN or Inf (arrays: host copies of the
        values the stage defines, e.g. only the visible Gaussians' rows)."""
        for name, values in arrays.items():
            bad = ~np.isfinite(values)
            if bad.any():
                first = tuple(int(i) for i in np.argwhere(bad)[0])
                raise NonFiniteError(stage, name, self.at, int(bad.sum()), int(values.size), first)
