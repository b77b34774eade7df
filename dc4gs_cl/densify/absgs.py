"""AbsGS: split on the homodirectional gradient (the sum of |g_x|, |g_y| over pixels, so opposite
gradients do not cancel) with its own threshold, clone on the 3DGS one; a smaller percent_dense and an
opacity clamp at 0.8 every 500 iterations."""
from __future__ import annotations

from ..config import DensifyConfig
from ..statistics import ABS_PER_VIEW
from .strategy import Strategy


class AbsGS(Strategy):
    name = "absgs"
    base_split_criterion = ABS_PER_VIEW

    @staticmethod
    def default_config() -> DensifyConfig:
        return DensifyConfig(split_threshold=4e-4, percent_dense=0.001, opacity_clamp_every=500)
