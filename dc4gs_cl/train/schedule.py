"""The 3DGS recipe's schedules (written for RECIPE_ITERATIONS iterations), scaled to a run's length: the
densification strategy's window and opacity steps, the SH degree steps and the learning rates."""
from __future__ import annotations

from dataclasses import replace

from ..config import RECIPE_ITERATIONS, TrainConfig
from ..densify import STRATEGIES, Strategy
from ..optim.adam import delayed_lr, exponential_lr
from ..optim.batch_gradients import batch_rate_factor

MIN_DENSIFY_STEPS = 10   # a short run still densifies about this often
SH_DEGREE_EVERY = 1_000  # one more SH degree every this many (scaled) iterations
EVALUATE_AT = (7_000,)   # test views evaluated at these (scaled) iterations and at the end, as the Inria code
# --exposure: the corrections' rate starts at EXPOSURE_DELAY_MULT of itself and rises to the full rate over the
# first EXPOSURE_DELAY of the run (the Inria code's lr_delay_steps and lr_delay_mult, which it leaves at 0 for
# exposure): the first renders are too crude for a photo's correction to be told from the model's error, and what
# the corrections take up then, the model is densified around (README, exposure compensation)
EXPOSURE_DELAY, EXPOSURE_DELAY_MULT = 0.1, 0.01


# TrainConfig's settings that replace the strategy's (DensifyConfig's field of the same name) as given, unscaled
SCHEDULE_OVERRIDES = ("densify_from", "densify_every", "opacity_reset_every", "densify_until", "split_threshold",
                      "max_gaussians")


class Schedule:
    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg

    def scaled(self, steps: int) -> int:
        """An iteration count of the recipe, scaled to this run's length."""
        return max(1, round(steps * self.cfg.iterations / RECIPE_ITERATIONS))

    def strategy(self) -> Strategy:
        """The run's strategy with its schedule scaled to the run's length. The interval between densification
        steps of a strategy that gathers gradient statistics is not scaled, as the statistics need that many views
        and new Gaussians that many steps to settle (scaling it grows the model explosively); with --batch B it is
        that many views, 1/B as many iterations, and it shrinks only where fewer than MIN_DENSIFY_STEPS would fit in
        the window. A strategy with scaled_interval has it scaled as gsplat's steps_scaler scales MCMC's: MCMC
        gathers nothing, its growth per step is bounded by the cap, and a short run keeps the full schedule's
        number of steps (at 3,000 iterations 24 steps of 5% would grow the model 3.2x at most, short of any cap)."""
        cls = STRATEGIES[self.cfg.strategy]
        base = cls.default_config()
        start, stop = self.scaled(base.densify_from), self.scaled(base.densify_until)
        if cls.scaled_interval:
            every = self.scaled(base.densify_every)
        else:   # that many views: a batch of B views gathers them in 1/B as many iterations (Grendel counts views)
            every = min(max(1, round(base.densify_every / self.cfg.batch)), max(1, (stop - start) // MIN_DENSIFY_STEPS))
        c = replace(base, densify_from=start, densify_until=stop, densify_every=every,
                    big_world_after=self.scaled(base.big_world_after),
                    opacity_reset_every=self.scaled(base.opacity_reset_every),
                    opacity_clamp_every=None if base.opacity_clamp_every is None
                    else self.scaled(base.opacity_clamp_every))
        given = {name: value for name in SCHEDULE_OVERRIDES if (value := getattr(self.cfg, name)) is not None}
        return cls.for_run(replace(c, **given), self.cfg)

    def evaluations(self) -> list[int]:
        """The iterations after which the test views are evaluated: --eval-at, else EVALUATE_AT scaled; the
        last iteration always."""
        at = self.cfg.eval_at if self.cfg.eval_at is not None else tuple(self.scaled(i) for i in EVALUATE_AT)
        return sorted(set(at) | {self.cfg.iterations})

    def sh_degree(self, it: int) -> int:
        """Active SH degree at iteration it: one more every SH_DEGREE_EVERY (scaled), up to the model's."""
        return min(self.cfg.sh_degree, it // self.scaled(SH_DEGREE_EVERY))

    def learning_rates(self, it: int, extent: float, opacity_steps: bool) -> dict:
        """Each parameter group's rate at iteration it (the SH group: DC band, higher bands), times the batch's
        factor; the opacities are left out where they take no step."""
        c = self.cfg
        f = batch_rate_factor(c.batch)
        lrs = {"means": f * exponential_lr(it, c.lr_means * extent, c.lr_means_final * extent, c.iterations),
               "log_scales": f * c.lr_scales, "quats": f * c.lr_quats, "opacity_logits": f * c.lr_opacity,
               "sh": (f * c.lr_sh_dc, f * c.lr_sh_rest)}
        if not opacity_steps:
            del lrs["opacity_logits"]
        return lrs

    def exposure_lr(self, it: int) -> float:
        """--exposure's rate at iteration it: the Inria code's, log-linear from lr_exposure to lr_exposure_final
        over the run, delayed over its first EXPOSURE_DELAY (no batch factor: --exposure takes one view a step)."""
        c = self.cfg
        return (exponential_lr(it, c.lr_exposure, c.lr_exposure_final, c.iterations) *
                delayed_lr(it, round(EXPOSURE_DELAY * c.iterations), EXPOSURE_DELAY_MULT))
