"""A training run's settings: one frozen value, validated once, written to the run folder's config.json and
read back by --resume and eval (run_folder.py); with the densification settings it holds (DC4GSConfig, MCMC's
MCMCConfig) or a strategy takes (DensifyConfig), and the `train` flag that gives each setting (FLAGS).

Device-free (no OpenCL, no strategy classes), so that `report` and `export` import without a device
(tests/test_structure.py)."""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields

from .constants import LAMBDA_DSSIM, SH_MAX_DEGREE
from .errors import InputError
from .scene.camera import TEST_SPLITS

RECIPE_ITERATIONS = 30_000   # the 3DGS schedule is written for this many iterations; shorter runs scale it
OUTPUT_SETTINGS = ("save_at", "checkpoint_every", "eval_at")   # settings that do not change the trained model
DEFAULT_LINE_EVERY = 100     # --log-every: iterations between progress lines when the output is not a terminal
# The strategies' names, spelled here so that settings are checked without importing the strategies (device
# code); densify.STRATEGIES holds a class for each, in this order (tests/test_structure.py checks)
STRATEGY_NAMES = ("3dgs", "absgs", "pixelgs", "mcmc")
MCMC_DEFAULT_CAP = 1_000_000                 # MCMC's max_gaussians when --max-gaussians is not given: gsplat's cap_max
POOLINGS = ("view", "window")       # per view (the paper) or over the window (the authors' release)
SPLIT_PICKS = ("poly", "argmin", "dense", "middle")   # middle: DCS' split at x = 0.5, no costs (an ablation)
DCC_READINGS = ("abs", "base")
FIVE_CANDIDATES = 5                 # the paper's candidate count
DENSE_CANDIDATES = 59               # --split-pick dense without --split-candidates
# the most split candidates a line may have: each adds 5 sums per Gaussian to the backward's private and local
# arrays (kernels/sum_pairs.cl, rasterize_backward.cl); 10,001 crashed PoCL's compiled sum_pairs, 3,001 ran 60x slower
MAX_CANDIDATES = 99
MAX_SEED = 2 ** 63 - 1

# `train`'s flags -> the setting each gives: a TrainConfig field, or "<group>.<field>" of one of its nested settings
# (NESTED: "dc4gs.<field>" of its DC4GSConfig, "mcmc.<field>" of its MCMCConfig); in the fields' order, which
# --resume's list of differing settings follows. cli.py reads the settings given through it, and the checks below
# name a setting by its flag (FLAG_OF).
FLAGS = {
    "--scene": "scene", "--iterations": "iterations", "--strategy": "strategy", "--resolution": "resolution",
    "--test-every": "test_every", "--test-split": "test_split", "--white-background": "white_background",
    "--alpha-mask": "alpha_mask", "--seed": "seed", "--sh-degree": "sh_degree", "--save-at": "save_at",
    "--checkpoint-every": "checkpoint_every", "--eval-at": "eval_at", "--batch": "batch",
    "--position-lr-init": "lr_means", "--position-lr-final": "lr_means_final", "--feature-lr": "lr_sh_dc",
    "--feature-rest-lr": "lr_sh_rest", "--opacity-lr": "lr_opacity", "--scaling-lr": "lr_scales",
    "--rotation-lr": "lr_quats", "--lambda-dssim": "lambda_dssim", "--random-background": "random_background",
    "--densify-from-iter": "densify_from", "--densification-interval": "densify_every",
    "--opacity-reset-interval": "opacity_reset_every", "--densify-until": "densify_until",
    "--antialiased": "antialiased", "--mcmc-noise-lr": "mcmc.noise_lr", "--opacity-reg": "mcmc.opacity_reg",
    "--scale-reg": "mcmc.scale_reg",
    "--split-threshold": "split_threshold", "--max-gaussians": "max_gaussians", "--low-memory": "low_memory",
    "--dcc": "dc4gs.dcc", "--dcs": "dc4gs.dcs", "--dc-pooling": "dc4gs.pooling", "--split-pick": "dc4gs.split_pick",
    "--split-candidates": "dc4gs.candidates", "--dcc-reading": "dc4gs.dcc_reading", "--dcs-track": "dc4gs.track",
    "--dcs-other-scale": "dc4gs.other_scale", "--dcs-every": "dc4gs.cost_every"}
FLAG_OF = {setting: flag for flag, setting in FLAGS.items()}


def flag_key(flag: str) -> str:
    """A flag's name as argparse stores it (--dc-pooling: dc_pooling)."""
    return flag[2:].replace("-", "_")


def flagged_problems(checks: list[tuple[str, bool, str]]) -> list[str]:
    """The messages of the failed checks, (setting, failed, what is wrong), each naming the setting's flag."""
    return [f"{FLAG_OF[setting]} {text}" for setting, failed, text in checks if failed]


@dataclass(frozen=True)
class DensifyConfig:
    """A strategy's densification hyperparameters (densify.strategy.Strategy.default_config); the run's
    schedule scales them to its length (train.schedule)."""
    densify_from: int = 500            # densify at iterations densify_from < it < densify_until ...
    densify_until: int = 15_000        # ... that are multiples of densify_every; statistics gather up to the last
    densify_every: int = 100
    clone_threshold: float = 2e-4      # on the mean per-view criterion, NDC units
    split_threshold: float = 2e-4
    percent_dense: float = 0.01        # "small" = largest scale <= percent_dense * extent: clone, else split
    prune_opacity: float = 0.005
    big_world_after: int = 3_000       # after this iteration also prune largest scale > big_world_fraction * extent
    big_world_fraction: float = 0.1
    screen_size_px: float | None = None  # the 3DGS screen-size rule (radius > 20 px); off: never fires in the releases
    opacity_reset_every: int = 3_000   # 0: never
    opacity_reset_to: float = 0.01
    opacity_clamp_every: int | None = None   # AbsGS: clamp opacities to <= opacity_clamp this often
    opacity_clamp: float = 0.8
    max_gaussians: int | None = None   # densification never grows the model past this (cap_growth)


@dataclass(frozen=True)
class DC4GSConfig:
    """DC4GS' settings (densify/dc4gs.py: its criterion and split position); off unless dcc or dcs (every
    setting is still checked, so that a mistyped flag never passes silently)."""
    dcc: bool = False               # DC-weighted split criterion
    dcs: bool = False               # DC-guided split placement
    pooling: str = "view"
    split_pick: str = "poly"
    candidates: int | None = None   # odd; None: FIVE_CANDIDATES, or DENSE_CANDIDATES with split_pick "dense"
    dcc_reading: str = "base"       # base: (1 - kappa) x the base's own per-view term; abs: (1 - kappa) |ghat|
    track: float = 0.0              # split costs only while the running split criterion >= track x threshold (0: exact)
    other_scale: float = 1.0        # DCS children's other two axes x this (1, the paper's: kept; release: const_scale)
    cost_every: int = 1             # split costs from every this-many-th iteration's view only (1: every view, exact)

    def __post_init__(self):
        if problems := self.problems():
            raise ValueError("; ".join(problems))

    @property
    def enabled(self) -> bool:
        return self.dcc or self.dcs

    @property
    def costs_pick(self) -> bool:
        """Whether DCS' split position comes from the candidates' costs (not with split_pick middle)."""
        return self.dcs and self.split_pick != "middle"

    @property
    def candidate_count(self) -> int:
        if self.candidates is not None:
            return self.candidates
        return DENSE_CANDIDATES if self.split_pick == "dense" else FIVE_CANDIDATES

    @property
    def label(self) -> str:
        """DC4GS, DCC or DCS: what a strategy's name gets appended."""
        return "DC4GS" if self.dcc and self.dcs else ("DCC" if self.dcc else "DCS")

    def problems(self) -> list[str]:
        """What is wrong with these settings, named by their command-line flags (empty: nothing)."""
        return flagged_problems([
            *((f"dc4gs.{name}", value not in allowed, f"{value!r} is not one of {', '.join(allowed)}")
              for name, value, allowed in (("pooling", self.pooling, POOLINGS),
                                           ("split_pick", self.split_pick, SPLIT_PICKS),
                                           ("dcc_reading", self.dcc_reading, DCC_READINGS))),
            ("dc4gs.candidates", not 3 <= self.candidate_count <= MAX_CANDIDATES or self.candidate_count % 2 == 0,
             f"{self.candidate_count} must be odd, 3..{MAX_CANDIDATES}"),
            ("dc4gs.track", not 0 <= self.track <= 1, f"{self.track} must lie in [0, 1]"),
            ("dc4gs.other_scale", not 0 < self.other_scale <= 1, f"{self.other_scale} must lie in (0, 1]"),
            ("dc4gs.cost_every", self.cost_every < 1, f"{self.cost_every} must be at least 1"),
            # window pooling costs the sides' running sums at every visible view, which a skipped view cannot add to
            ("dc4gs.cost_every", self.cost_every > 1 and self.pooling == "window",
             f"{self.cost_every} needs {FLAG_OF['dc4gs.pooling']} view")])


@dataclass(frozen=True)
class MCMCConfig:
    """MCMC's own settings (densify/mcmc.py; --strategy mcmc only): the position noise's rate (times the position
    learning rate) and the loss' regularisers opacity_reg mean(opacity) + scale_reg mean(scale), gsplat's defaults.
    TrainConfig checks them (checks), as they apply to its strategy."""
    noise_lr: float = 5e5
    opacity_reg: float = 0.01
    scale_reg: float = 0.01

    def checks(self, strategy: str) -> list[tuple[str, bool, str]]:
        """The checks of these settings in a run of this strategy, as flagged_problems takes them."""
        values = [(f"mcmc.{f.name}", getattr(self, f.name), f.default) for f in fields(self)]
        return [*((name, not (math.isfinite(value) and value >= 0), f"{value} must be a finite number >= 0")
                  for name, value, _ in values),
                *((name, strategy != "mcmc" and value != default, "applies to --strategy mcmc only")
                  for name, value, default in values)]


# TrainConfig's nested settings, by field; config.json of runs made before they were nested held them flat, under
# their flag's key (FLAT_KEYS: group -> {key: field})
NESTED = {"dc4gs": DC4GSConfig, "mcmc": MCMCConfig}
FLAT_KEYS = {group: {flag_key(flag): setting.removeprefix(f"{group}.") for flag, setting in FLAGS.items()
                     if setting.startswith(f"{group}.")} for group in NESTED}


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
    batch: int = 1                         # views per optimiser step (an iteration), over all processes (optim/batch.py)
    # learning rates (3DGS); the position's decays log-linearly over the run and scales with the extent
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20        # the Inria code's feature_lr / 20 (cli.py keeps the ratio for --feature-lr)
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lambda_dssim: float = LAMBDA_DSSIM     # L = (1 - lambda_dssim) L1 + lambda_dssim (1 - SSIM)
    random_background: bool = False        # each iteration renders onto a random colour (the target unchanged)
    # overrides of the strategy's schedule, which is otherwise scaled to the run (train.schedule)
    densify_from: int | None = None        # the densification window's start
    densify_every: int | None = None       # iterations between densification steps
    opacity_reset_every: int | None = None # 0: no opacity resets
    densify_until: int | None = None       # the window's end; 0 disables densification
    antialiased: bool = False              # opacities times their 2D filter's compensation (gsplat's antialiased)
    mcmc: MCMCConfig = MCMCConfig()        # --strategy mcmc only
    split_threshold: float | None = None   # override the strategy's split threshold (its criterion's units)
    max_gaussians: int | None = None       # densification never grows the model past this many Gaussians
    low_memory: bool = False               # backward sums with float atomics, no per-pair slots (not bit-reproducible)
    dc4gs: DC4GSConfig = DC4GSConfig()     # off unless dcc or dcs

    def __post_init__(self):
        problems = flagged_problems([
            ("iterations", self.iterations < 1, f"{self.iterations} must be at least 1"),
            ("strategy", self.strategy not in STRATEGY_NAMES,
             f"{self.strategy!r} is not one of {', '.join(STRATEGY_NAMES)}"),
            ("save_at", any(s < 1 or s > self.iterations for s in self.save_at),
             f"{list(self.save_at)} must lie in 1..{self.iterations}"),
            ("eval_at", self.eval_at is not None and any(s < 1 or s > self.iterations for s in self.eval_at),
             f"{list(self.eval_at or ())} must lie in 1..{self.iterations}"),
            ("test_every", self.test_every < 0, f"{self.test_every} must be 0 (no test views) or positive"),
            ("test_split", self.test_split not in TEST_SPLITS,
             f"{self.test_split!r} is not one of {', '.join(TEST_SPLITS)}"),
            ("split_threshold", self.split_threshold is not None
             and not (math.isfinite(self.split_threshold) and self.split_threshold > 0),
             f"{self.split_threshold} must be a positive number"),
            ("checkpoint_every", self.checkpoint_every < 1, f"{self.checkpoint_every} must be at least 1"),
            ("batch", self.batch < 1, f"{self.batch} must be at least 1"),
            *((name, value is not None and value < least, f"{value} must be >= {least}")
              for name, value, least in (("densify_until", self.densify_until, 0), ("densify_from", self.densify_from, 0),
                                         ("densify_every", self.densify_every, 1),
                                         ("opacity_reset_every", self.opacity_reset_every, 0))),
            ("lambda_dssim", not 0 <= self.lambda_dssim <= 1, f"{self.lambda_dssim} must lie in [0, 1]"),
            *self.mcmc.checks(self.strategy),
            ("strategy", self.strategy == "mcmc" and self.dc4gs.dcc,
             "mcmc: of DC4GS only --dcs applies (DCC weights a split criterion; MCMC splits nothing, it places "
             "copies)"),
            ("dc4gs.track", self.strategy == "mcmc" and self.dc4gs.track > 0,
             "does not apply to --strategy mcmc (it tracks a split criterion; MCMC has none)"),
            ("max_gaussians", self.max_gaussians is not None and self.max_gaussians < 1,
             f"{self.max_gaussians} must be at least 1"),
            ("sh_degree", not 0 <= self.sh_degree <= SH_MAX_DEGREE, f"{self.sh_degree} must be 0..{SH_MAX_DEGREE}"),
            ("seed", not 0 <= self.seed <= MAX_SEED, f"{self.seed} must be 0..2^63-1")])
        problems += flagged_problems([(f.name, not (math.isfinite(getattr(self, f.name)) and getattr(self, f.name) >= 0),
                                       f"{getattr(self, f.name)} must be a finite number >= 0")
                                      for f in fields(TrainConfig) if f.name.startswith("lr_")])
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
        nested = {}
        for group in NESTED:
            values = out.get(group, {})
            if not isinstance(values, dict):
                raise ValueError(f"{group}: expected a JSON object, got {values!r}")
            nested[group] = {**{field: d[key] for key, field in FLAT_KEYS[group].items() if key in d}, **values}
        check_json_types(TrainConfig, out, skip=tuple(NESTED))
        for group, values in nested.items():
            check_json_types(NESTED[group], values, prefix=f"{group}.")
        out["save_at"] = tuple(out.get("save_at", ()))
        if out.get("eval_at") is not None:
            out["eval_at"] = tuple(out["eval_at"])
        out.update({group: NESTED[group](**values) for group, values in nested.items()})
        return TrainConfig(**out)

    @staticmethod
    def from_settings(settings: dict) -> TrainConfig:
        """A run's settings named as FLAGS names them ("dc4gs.dcc": the nested DC4GSConfig's dcc); InputError for
        a wrong one (every nested setting is checked, whatever the strategy and DC4GS on or off: a mistyped flag
        never passes)."""
        nested = {group: {k.removeprefix(f"{group}."): v for k, v in settings.items() if k.startswith(f"{group}.")}
                  for group in NESTED}
        try:
            groups = {group: NESTED[group](**values) for group, values in nested.items()}
        except ValueError as e:   # DC4GSConfig checks itself
            raise InputError(None, str(e)) from None
        return TrainConfig(**{k: v for k, v in settings.items() if "." not in k}, **groups)


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
