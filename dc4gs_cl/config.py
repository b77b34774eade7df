"""A training run's settings: one frozen value, validated once, written to the run folder's config.json and
read back by --resume and eval (run_folder.py)."""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields

from .constants import SH_MAX_DEGREE
from .errors import InputError
from .host.densify import STRATEGIES
from .host.densify.dc4gs import DC4GSConfig
from .scene.camera import TEST_SPLITS

RECIPE_ITERATIONS = 30_000   # the 3DGS schedule is written for this many iterations; shorter runs scale it
OUTPUT_SETTINGS = ("save_at", "checkpoint_every", "eval_at")   # settings that do not change the trained model
# config.json of runs made before the DC4GS settings were nested: flat key -> DC4GSConfig field
FLAT_DC4GS_KEYS = {"dcc": "dcc", "dcs": "dcs", "dc_pooling": "pooling", "split_pick": "split_pick",
                   "split_candidates": "candidates", "dcc_reading": "dcc_reading", "dcs_track": "track"}


@dataclass(frozen=True)
class TrainConfig:
    scene: str
    iterations: int = RECIPE_ITERATIONS
    strategy: str = "3dgs"
    resolution: int | None = None
    test_every: int = 8
    test_split: str = "llff"              # which images are held out (scene.camera.split_train_test)
    white_background: bool = False
    alpha_mask: bool = False               # images' alpha masks pixels out instead of being composited
    seed: int = 0
    sh_degree: int = SH_MAX_DEGREE
    save_at: tuple[int, ...] = ()          # PLYs at these iterations (the last one is always saved)
    checkpoint_every: int = 1_000
    eval_at: tuple[int, ...] | None = None  # test views evaluated after these iterations (None: the recipe's)
    # learning rates (3DGS); the position's decays log-linearly over the run and scales with the extent
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    densify_until: int | None = None       # override the strategy's (scaled) window end; 0 disables densification
    split_threshold: float | None = None   # override the strategy's split threshold (its criterion's units)
    max_gaussians: int | None = None       # densification never grows the model past this many Gaussians
    low_memory: bool = False               # backward sums with float atomics, no per-pair slots (not bit-reproducible)
    dc4gs: DC4GSConfig = DC4GSConfig()     # off unless dcc or dcs

    def __post_init__(self):
        problems = []
        if self.iterations < 1:
            problems.append(f"--iterations {self.iterations} must be at least 1")
        if self.strategy not in STRATEGIES:
            problems.append(f"--strategy {self.strategy!r} is not one of {', '.join(STRATEGIES)}")
        if any(s < 1 or s > self.iterations for s in self.save_at):
            problems.append(f"--save-at {list(self.save_at)} must lie in 1..{self.iterations}")
        if self.eval_at is not None and any(s < 1 or s > self.iterations for s in self.eval_at):
            problems.append(f"--eval-at {list(self.eval_at)} must lie in 1..{self.iterations}")
        if self.test_every < 0:
            problems.append(f"--test-every {self.test_every} must be 0 (no test views) or positive")
        if self.test_split not in TEST_SPLITS:
            problems.append(f"--test-split {self.test_split!r} is not one of {', '.join(TEST_SPLITS)}")
        if self.split_threshold is not None and not (math.isfinite(self.split_threshold) and self.split_threshold > 0):
            problems.append(f"--split-threshold {self.split_threshold} must be a positive number")
        if self.checkpoint_every < 1:
            problems.append(f"--checkpoint-every {self.checkpoint_every} must be at least 1")
        if self.densify_until is not None and self.densify_until < 0:
            problems.append(f"--densify-until {self.densify_until} must be >= 0")
        if self.max_gaussians is not None and self.max_gaussians < 1:
            problems.append(f"--max-gaussians {self.max_gaussians} must be at least 1")
        if not 0 <= self.sh_degree <= SH_MAX_DEGREE:
            problems.append(f"--sh-degree {self.sh_degree} must be 0..{SH_MAX_DEGREE}")
        if problems:
            raise InputError(None, "; ".join(problems))

    def differences(self, other: "TrainConfig") -> dict[str, tuple]:
        """name -> (this, other) for the settings that change the trained model and differ."""
        return {f.name: (getattr(self, f.name), getattr(other, f.name)) for f in fields(TrainConfig)
                if f.name not in OUTPUT_SETTINGS and getattr(self, f.name) != getattr(other, f.name)}

    def to_json(self) -> dict:
        d = asdict(self)
        d["save_at"] = list(self.save_at)
        d["eval_at"] = None if self.eval_at is None else list(self.eval_at)
        return d

    @staticmethod
    def from_json(d: dict) -> "TrainConfig":
        """The inverse of to_json (unknown keys ignored); ValueError naming the setting for a value of the
        wrong JSON type, InputError or ValueError for a value out of range."""
        if not isinstance(d, dict):
            raise ValueError(f"expected a JSON object, got {type(d).__name__}")
        known = {f.name for f in fields(TrainConfig)}
        out = {k: v for k, v in d.items() if k in known}
        flat = {field: d[key] for key, field in FLAT_DC4GS_KEYS.items() if key in d}
        nested = out.get("dc4gs", {})
        if not isinstance(nested, dict):
            raise ValueError(f"dc4gs: expected a JSON object, got {nested!r}")
        dc4gs = {**flat, **nested}
        check_json_types(TrainConfig, out, skip=("dc4gs",))
        check_json_types(DC4GSConfig, dc4gs, prefix="dc4gs.")
        out["save_at"] = tuple(out.get("save_at", ()))
        if out.get("eval_at") is not None:
            out["eval_at"] = tuple(out["eval_at"])
        out["dc4gs"] = DC4GSConfig(**dc4gs)
        return TrainConfig(**out)


def _json_type_ok(annotation: str, value) -> bool:
    """Whether a value read from JSON fits a field's annotation (the few kinds the settings use)."""
    if annotation.endswith(" | None"):
        return value is None or _json_type_ok(annotation[: -len(" | None")], value)
    if annotation == "bool":
        return isinstance(value, bool)
    if annotation == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if annotation == "float":
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if annotation == "str":
        return isinstance(value, str)
    if annotation == "tuple[int, ...]":   # a JSON list
        return isinstance(value, list) and all(_json_type_ok("int", v) for v in value)
    raise AssertionError(f"no JSON check for the annotation {annotation!r}")


def check_json_types(cls, values: dict, prefix: str = "", skip: tuple[str, ...] = ()) -> None:
    """Raise ValueError naming the first setting whose JSON value does not fit the dataclass field's type."""
    annotations = {f.name: f.type for f in fields(cls)}
    for name, value in values.items():
        if name in annotations and name not in skip and not _json_type_ok(annotations[name], value):
            raise ValueError(f"{prefix}{name}: expected {annotations[name]}, got {json.dumps(value)[:40]}")
