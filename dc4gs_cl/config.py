"""A training run's settings: one frozen value, validated once, written to the run folder's config.json and
read back by --resume and eval (run_folder.py); with the densification settings it holds (DC4GSConfig, MCMC's
MCMCConfig) or a strategy takes (DensifyConfig), and the `train` flags, each declared once with the setting it gives
(TRAIN_FLAGS: the command line is built from them, and every check names a setting by its flag).

Device-free (no OpenCL, no strategy classes), so that `report` and `export` import without a device
(tests/test_structure.py)."""
from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, is_dataclass
from functools import reduce
from pathlib import Path

from .constants import LAMBDA_DSSIM, SH_MAX_DEGREE
from .errors import InputError
from .scene.builtin import BUILTIN_SCENE
from .scene.camera import TEST_SPLITS

RECIPE_ITERATIONS = 30_000   # the 3DGS schedule is written for this many iterations; shorter runs scale it
BUILTIN_ITERATIONS = 5_000   # the default run on the built-in scene: 5 to 9 minutes on 2 CPU cores
# settings that do not change the trained model
OUTPUT_SETTINGS = ("save_at", "checkpoint_every", "eval_at", "corrected_metrics")
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


# the `train` flags -----------------------------------------------------------------------------------------------
def downscale_factor(value: str) -> int:
    """-r's value (train and render)."""
    r = int(value)
    if r < 1:
        raise argparse.ArgumentTypeError("-r must be a positive integer (1, 2, 4, 8, ...)")
    return r


@dataclass(frozen=True)
class Flag:
    """A `train` flag, declared once: its argument is built from this (apps/train.py), and the checks name its
    setting by it (FLAG_OF). Each defaults to None: not given."""
    name: str                          # "--seed"
    setting: str | None                # the TrainConfig field it gives, or "<group>.<field>" of a group's (SETTINGS);
                                       # None: the command's own (its others follow these: apps/train.py)
    help: str                          # "{default}" in it: the setting's default (DEFAULT_SETTINGS)
    type: Callable | None = None       # of its value; bool: a switch, no value
    choices: tuple[str, ...] | None = None
    nargs: str | None = None           # "*": a list of values
    short: str | None = None           # "-r"

    @property
    def text(self) -> str:
        """The help, with the setting's default."""
        return self.help.format(default=setting_value(DEFAULT_SETTINGS, self.setting)) if "{default" in self.help \
            else self.help


@dataclass(frozen=True)
class FlagGroup:
    """Flags that --help lists together, in their order."""
    title: str | None                  # None: the command's options (the first section)
    flags: tuple[Flag, ...]
    metavars: bool = False             # values shown as N (integers) and X (numbers)
    inria_spellings: bool = False      # each flag also spelled with underscores, as the Inria code's (--feature_lr)


ANTIALIASED_HELP = ("antialiased rasterization (gsplat's rasterize_mode \"antialiased\", Mip-Splatting's 2D filter): "
                    "each opacity scaled by sqrt(det(Sigma) / det(Sigma + 0.3 I)), so that the 0.3 px^2 dilation "
                    "keeps a Gaussian's integral; renders at other resolutions than trained alias less")
TRAIN_FLAGS = (   # in the order `train --help` lists them (the first group's flags are listed before the others')
    FlagGroup(None, (
        Flag("--scene", "scene", f'COLMAP or NeRF scene folder, or "{BUILTIN_SCENE}" (the default)'),
        Flag("--out", None, "output folder (default output/<scene>-<date-time>): point_cloud/iteration_N/"
                            "point_cloud.ply, cameras.json, config.json, checkpoint.npz, results.json, test/ renders",
             Path),
        Flag("--strategy", "strategy", "densification: the 3dgs, absgs or pixelgs criterion (each with DC4GS or "
                                       "without), or mcmc (relocation and growth up to --max-gaussians, position "
                                       "noise; see the MCMC options) ({default})",
             choices=tuple(sorted(STRATEGY_NAMES))),
        Flag("--iterations", "iterations", f"training iterations (default {RECIPE_ITERATIONS:,}; "
                                           f"{BUILTIN_ITERATIONS:,} for the built-in scene). Runs shorter than "
                                           f"{RECIPE_ITERATIONS:,} scale the 3DGS schedule to their length", int),
        Flag("--resolution", "resolution", "downscale images by this factor (default: widths above 1600 px scaled to "
                                           "1600)", downscale_factor, short="-r"),
        Flag("--test-every", "test_every", "every N-th image (by name) is a test image ({default}; 0: none)", int),
        Flag("--test-split", "test_split", "which images are held out, by name: llff (default) from the first, so "
                                           "the path's first view is a test view (an extrapolation); interpolated: as "
                                           "many, spread inside the path, each with training views on both sides",
             choices=TEST_SPLITS),
        Flag("--save-at", "save_at", "also write the PLY at these iterations (default: none; the last iteration's "
                                     "always)", int, nargs="*"),
        Flag("--eval-at", "eval_at", "evaluate the test views after these iterations too, into metrics.jsonl "
                                     "(default: 7,000 scaled to the run, as the Inria code; the last iteration always)",
             int, nargs="*"),
        Flag("--checkpoint-every", "checkpoint_every", "iterations between checkpoints ({default})", int),
        Flag("--seed", "seed", "random seed: the same seed gives the same model ({default})", int),
        Flag("--sh-degree", "sh_degree", f"largest spherical-harmonics degree, 0 to {SH_MAX_DEGREE} ({{default}})",
             int),
        Flag("--white-background", "white_background", "white background (Blender scenes)", bool),
        Flag("--alpha-mask", "alpha_mask", "images' alpha channel masks pixels out (no loss, no densification "
                                           "statistics) instead of being composited onto the background; a masks/ "
                                           "folder beside images/ is always used", bool),
        Flag("--undistort", "undistort", "undistort distorted photos to a pinhole and train on those (cropped and "
                                         "resampled), instead of rendering their camera model directly (the default "
                                         "for COLMAP's SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, OPENCV_FISHEYE, "
                                         "RADIAL_FISHEYE and SIMPLE_RADIAL_FISHEYE and NeRF transforms' k1..k4, p1, "
                                         "p2 and fisheye); other models need it", bool),
        Flag("--split-threshold", "split_threshold", "split Gaussians whose split criterion reaches this (default: "
                                                     "the strategy's, 2e-4 for 3dgs and pixelgs, 4e-4 for absgs); a "
                                                     "higher one splits less. With DCC the criterion is DC-weighted "
                                                     "and the threshold the same", float),
        Flag("--batch", "batch", "views per optimiser step (an iteration), their gradients' mean stepping the model; "
                                 "the learning rates times sqrt(B) and Adam's betas to the power B (Grendel's rule), "
                                 "so that --iterations N/B sees as many views as N iterations of one (1; under "
                                 "mpirun: the processes' count, each its share of the views)", int),
        Flag("--max-gaussians", "max_gaussians", "a cap, not a target: densification never grows the model past N "
                                                 "Gaussians. A step that would takes its clone and split candidates "
                                                 "by their criterion over its threshold, highest first; pruning goes "
                                                 "on as usual (default: no cap)", int),
        Flag("--antialiased", "antialiased", ANTIALIASED_HELP + " (default off)", bool),
        Flag("--exposure", "exposure", "learn a 3x4 affine colour correction per training photo (the Inria code's "
                                       "exposure compensation), applied to the render before the loss, their mean "
                                       "held at the identity; test views are rendered without one. In the run "
                                       "folder's exposure.json, never in the model (default off)", bool),
        Flag("--corrected-metrics", "corrected_metrics", "also score the test views after a colour correction "
                                                         "fitted on each view's left half, on its right half (the "
                                                         "Inria code's protocol), labelled corrected beside the raw "
                                                         "metrics (default off)", bool))),
    FlagGroup("the 3DGS recipe (the Inria code's names; the schedule's iterations are scaled to runs shorter than "
              f"{RECIPE_ITERATIONS:,} unless given here)", (
        Flag("--position-lr-init", "lr_means", "position learning rate at the start, times the scene's extent "
                                               "({default:g})", float),
        Flag("--position-lr-final", "lr_means_final", "... at the end, decayed log-linearly ({default:g})", float),
        Flag("--feature-lr", "lr_sh_dc", "SH DC band's learning rate ({default:g}; the higher bands' 1/20 of it)",
             float),
        Flag("--feature-rest-lr", "lr_sh_rest", "the higher SH bands' learning rate ({default:g}, or --feature-lr / "
                                                "20)", float),
        Flag("--opacity-lr", "lr_opacity", "opacity learning rate ({default:g})", float),
        Flag("--scaling-lr", "lr_scales", "log-scale learning rate ({default:g})", float),
        Flag("--rotation-lr", "lr_quats", "quaternion learning rate ({default:g})", float),
        Flag("--exposure-lr-init", "lr_exposure", "--exposure: the corrections' learning rate at the start, "
                                                  "reached after a delay over the run's first tenth ({default:g})",
             float),
        Flag("--exposure-lr-final", "lr_exposure_final", "... at the end, decayed log-linearly ({default:g})", float),
        Flag("--lambda-dssim", "lambda_dssim", "the SSIM term's weight in the loss, 0 to 1 ({default:g})", float),
        Flag("--random-background", "random_background", "render onto a random colour each iteration (default: the "
                                                         "scene's background)", bool),
        # the strategy's schedule (DensifyConfig), which the run scales to its length unless these are given
        Flag("--densify-from-iter", "densify_from", f"start of the densification window "
                                                    f"({DensifyConfig.densify_from:,}, scaled)", int),
        Flag("--densify-until", "densify_until", f"end of the densification window ({DensifyConfig.densify_until:,}, "
                                                 "scaled; 0: no densification)", int),
        Flag("--densification-interval", "densify_every", f"iterations between densification steps "
                                                          f"({DensifyConfig.densify_every}; fewer where a short run's "
                                                          "window would hold under 10 steps; --batch B: 100 / B; "
                                                          "mcmc: scaled)", int),
        Flag("--opacity-reset-interval", "opacity_reset_every", f"iterations between opacity resets "
                                                                f"({DensifyConfig.opacity_reset_every:,}, scaled; "
                                                                "0: none)", int)), metavars=True, inria_spellings=True),
    FlagGroup(f"MCMC (--strategy mcmc; its cap is --max-gaussians, default {MCMC_DEFAULT_CAP:,})", (
        Flag("--mcmc-noise-lr", "mcmc.noise_lr", "the position noise's rate, times the position learning rate "
                                                 "({default:g})", float),
        Flag("--opacity-reg", "mcmc.opacity_reg", "the loss term X mean(opacity) ({default:g})", float),
        Flag("--scale-reg", "mcmc.scale_reg", "the loss term X mean(scale) ({default:g})", float)), metavars=True),
    FlagGroup("DC4GS (directional-consistency density control, on any base strategy)", (
        Flag("--dc4gs", None, "DCC and DCS together", bool),
        Flag("--dcc", "dc4gs.dcc", "DC-weighted split criterion: a Gaussian is split only where its pixels' gradients "
                                   "disagree", bool),
        Flag("--dcs", "dc4gs.dcs", "DC-guided split: children placed on the principal axis where the costs say, not "
                                   "at random", bool),
        Flag("--dc-pooling", "dc4gs.pooling", "directional consistency per view (view: the paper; default) or over "
                                              "the densification window (window: the authors' release)",
             choices=POOLINGS),
        Flag("--split-pick", "dc4gs.split_pick", "split position: minimum of the polynomial through the candidates' "
                                                 "costs (poly, default), the best candidate (argmin), the best of "
                                                 f"many candidates (dense: {DENSE_CANDIDATES}), or the middle, no "
                                                 "costs gathered (middle: an ablation, DCS' split without its "
                                                 "placement)", choices=SPLIT_PICKS),
        Flag("--split-candidates", "dc4gs.candidates", f"candidate split positions (odd; default {FIVE_CANDIDATES})",
             int),
        Flag("--dcs-track", "dc4gs.track", "gather split costs for a Gaussian only in its first views of a window and "
                                           "while its running split criterion is at least this fraction of the "
                                           "threshold (0: every Gaussian that can be split, exact; see the README)",
             float),
        Flag("--dcs-every", "dc4gs.cost_every", "add to the split costs only every this-many-th iteration's view (1: "
                                                "every view, exact, default; an approximation that skips the split "
                                                "sums' cost in the other views: see the README)", int),
        Flag("--dcs-other-scale", "dc4gs.other_scale", "DCS' children's two other axes times this (1: kept, the "
                                                       "paper's, default; 0.625 shrinks them as the 3DGS split does: "
                                                       "see the README on regions of large Gaussians)", float),
        Flag("--dcc-reading", "dc4gs.dcc_reading", "what DCC weights on the 3DGS and Pixel-GS bases: the base's own "
                                                   "term (base, the paper's literal reading; default) or the "
                                                   "homodirectional gradient (abs)", choices=DCC_READINGS))),
    FlagGroup(None, (
        Flag("--low-memory", "low_memory", "the backward adds into per-Gaussian sums with float atomics instead of "
                                           "per-pair slots: about 17%% less device memory, as fast, not "
                                           "bit-reproducible from run to run", bool),)))
# a setting -> the flag that gives it: every check names the setting by it
FLAG_OF = {flag.setting: flag.name for group in TRAIN_FLAGS for flag in group.flags if flag.setting}


def flag_key(flag: str) -> str:
    """A flag's name as argparse stores it (--dc-pooling: dc_pooling)."""
    return flag[2:].replace("-", "_")


def flagged_problems(checks: list[tuple[str, bool, str]]) -> list[str]:
    """The messages of the failed checks, (setting, failed, what is wrong), each naming the setting's flag
    (FLAG_OF)."""
    return [f"{FLAG_OF[setting]} {text}" for setting, failed, text in checks if failed]


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
    undistort: bool = False                # distorted photos undistorted to pinholes, not rendered through their model
    seed: int = 0
    sh_degree: int = SH_MAX_DEGREE
    save_at: tuple[int, ...] = ()          # PLYs at these iterations (the last one is always saved)
    checkpoint_every: int = 1_000
    eval_at: tuple[int, ...] | None = None  # test views evaluated after these iterations (None: the recipe's)
    batch: int = 1                         # views per optimiser step (an iteration), over all processes
                                           # (optim/batch_gradients.py)
    # learning rates (3DGS); the position's decays log-linearly over the run and scales with the extent
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20        # the Inria code's feature_lr / 20 (kept for --feature-lr: apps/train.py)
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_exposure: float = 0.01              # --exposure's corrections (the Inria code's exposure_lr_init, _final)
    lr_exposure_final: float = 0.001
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
    exposure: bool = False                 # a colour correction per training photo (backward/exposure.py)
    corrected_metrics: bool = False        # test views also scored after a fitted correction (evaluation)

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
            # the corrections step once a view (their gradient is not summed over a batch's views)
            ("exposure", self.exposure and self.batch > 1,
             f"needs --batch 1, one process (here a batch of {self.batch})"),
            *((name, value is not None and value < least, f"{value} must be >= {least}")
              for name, value, least in (("densify_until", self.densify_until, 0),
                                         ("densify_from", self.densify_from, 0),
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
        problems += flagged_problems([(f.name, not (math.isfinite(getattr(self, f.name))
                                                    and getattr(self, f.name) >= 0),
                                       f"{getattr(self, f.name)} must be a finite number >= 0")
                                      for f in fields(TrainConfig) if f.name.startswith("lr_")])
        if problems:
            raise InputError(None, "; ".join(problems))

    def differences(self, other: "TrainConfig") -> dict[str, tuple]:
        """setting -> (this, other) for the settings that change the trained model and differ, a group's named
        "<group>.<field>" (SETTINGS), in the fields' order."""
        return {name: (setting_value(self, name), setting_value(other, name)) for name in SETTINGS
                if name not in OUTPUT_SETTINGS and setting_value(self, name) != setting_value(other, name)}

    def to_json(self) -> dict:
        d = asdict(self)
        d["save_at"] = list(self.save_at)
        d["eval_at"] = None if self.eval_at is None else list(self.eval_at)
        return d

    @staticmethod
    def from_settings(settings: dict) -> TrainConfig:
        """The settings named as in FLAGS, a nested group's as "<group>.<field>" (the rest their defaults);
        InputError naming the flags of those that are wrong."""
        top, nested = {}, {group: {} for group in SETTING_GROUPS}
        for setting, value in settings.items():
            group, _, name = setting.rpartition(".")
            (nested[group] if group else top)[name] = value
        try:
            groups = {group: cls(**nested[group]) for group, cls in SETTING_GROUPS.items()}
        except ValueError as e:   # a group's settings are checked, the group on or off: a mistyped flag never passes
            raise InputError(None, str(e)) from None
        return TrainConfig(**top, **groups)

    @staticmethod
    def from_json(d: dict) -> "TrainConfig":
        """The inverse of to_json (unknown keys ignored); ValueError naming the setting for a value of the
        wrong JSON type, InputError or ValueError for a value out of range."""
        if not isinstance(d, dict):
            raise ValueError(f"expected a JSON object, got {type(d).__name__}")
        known = {f.name for f in fields(TrainConfig)}
        out = {k: v for k, v in d.items() if k in known}
        out.setdefault("undistort", True)   # settings from before direct rendering: those runs trained undistorted
        nested = {}
        for group in SETTING_GROUPS:
            values = out.get(group, {})
            if not isinstance(values, dict):
                raise ValueError(f"{group}: expected a JSON object, got {values!r}")
            nested[group] = {**{field: d[key] for key, field in FLAT_KEYS[group].items() if key in d}, **values}
        check_json_types(TrainConfig, out, skip=tuple(SETTING_GROUPS))
        for group, values in nested.items():
            check_json_types(SETTING_GROUPS[group], values, prefix=f"{group}.")
        out["save_at"] = tuple(out.get("save_at", ()))
        if out.get("eval_at") is not None:
            out["eval_at"] = tuple(out["eval_at"])
        out.update({group: SETTING_GROUPS[group](**values) for group, values in nested.items()})
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


# the settings ----------------------------------------------------------------------------------------------------
DEFAULT_SETTINGS = TrainConfig(scene=BUILTIN_SCENE)
# TrainConfig's fields that are groups of settings (dc4gs: DC4GSConfig), whose settings are named "<group>.<field>"
SETTING_GROUPS = {f.name: type(value) for f in fields(TrainConfig)
                  if is_dataclass(value := getattr(DEFAULT_SETTINGS, f.name))}


def setting_value(cfg: TrainConfig, setting: str):
    """A setting's value in cfg ("dc4gs.pooling": cfg.dc4gs.pooling)."""
    return reduce(getattr, setting.split("."), cfg)


def _setting_names(settings, prefix: str = ""):
    """Every setting of a settings value in its fields' order, a group's named "<group>.<field>"."""
    for f in fields(settings):
        value = getattr(settings, f.name)
        yield from _setting_names(value, f"{prefix}{f.name}.") if is_dataclass(value) else (prefix + f.name,)


SETTINGS = tuple(_setting_names(DEFAULT_SETTINGS))   # in the fields' order
# `train`'s flags -> the setting each gives, in the fields' order (SETTINGS), which --resume's list of differing
# settings follows; the command line reads the settings given through it
FLAGS = dict(sorted(((flag.name, flag.setting) for group in TRAIN_FLAGS for flag in group.flags if flag.setting),
                    key=lambda item: SETTINGS.index(item[1])))
# config.json of runs made before a group's settings were nested (DC4GS', MCMC's) held them flat, under their flag's
# key: group -> {key: field}
FLAT_KEYS = {group: {flag_key(flag): setting.removeprefix(f"{group}.") for flag, setting in FLAGS.items()
                     if setting.startswith(f"{group}.")} for group in SETTING_GROUPS}
