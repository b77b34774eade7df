"""Algorithm switches of the forward pipeline. The defaults are exact (or, for the exp, as accurate as
the driver's); the benchmark turns each off, or the approximation on, to measure it. And the rasterization
mode, which is the model's: a model trained antialiased renders antialiased."""
from __future__ import annotations

from dataclasses import dataclass

from ..runtime import RELAXED_MATH


@dataclass(frozen=True)
class RenderOptions:
    fast_exp: bool = True              # our polynomial exp (max rel. error 1.8e-7) instead of the driver's
    alpha_cut: bool = True             # pairs and tile rows only where alpha can reach 1/255 (exact)
    early_stop: bool = True            # a tile stops once all its pixels are saturated (exact)
    depth_sort_bits: int | None = None  # approximation: sort only the top bits of the depth keys
    relaxed_math: bool = False         # approximation: build the forward kernels with -cl-fast-relaxed-math
    antialiased: bool = False          # opacities times sqrt(det Sigma / det(Sigma + dilation)) (project.h)

    @staticmethod
    def of_model(antialiased: bool | None, trained: bool | None = None) -> "RenderOptions":
        """The options a trained model renders with: antialiased as given (render / view --(no-)antialiased),
        else as it trained, where that is known (its run's settings, or a .spz's flag), else off."""
        return RenderOptions(antialiased=bool(trained) if antialiased is None else antialiased)

    def defines(self) -> dict[str, int]:
        return {"FAST_EXP": int(self.fast_exp), "ALPHA_CUT": int(self.alpha_cut), "EARLY_STOP": int(self.early_stop),
                RELAXED_MATH: int(self.relaxed_math), "ANTIALIASED": int(self.antialiased)}
