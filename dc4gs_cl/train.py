"""Training: the 3DGS recipe on the device, with the host owning the schedules, Adam's logic and the
densification strategy; checkpoints written atomically, so that an interrupted run resumes.

One iteration: pick a training camera -> render -> loss and dL/dimage -> rasterizer backward (with the
densification statistics while the window is open) -> fold the statistics -> projection backward with
Adam's step fused in (skipped where 3DGS skips the step: on densification iterations, and for the opacity
on its resets).
Per iteration the host uploads the target image and reads back two counts (visible Gaussians, pairs);
the loss is read every few iterations for the progress bar.
"""
from __future__ import annotations

import json
import math
import signal
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from .constants import SH_MAX_DEGREE
from .errors import InputError
from .files import write_atomic, write_json
from .host.adam import Adam, exponential_lr
from .host.dc4gs import DENSE_CANDIDATES, DC4GSConfig
from .host.ops import GaussianSet
from .host.stats import WindowStats
from .host.strategy import STRATEGIES, Strategy
from .loss import Loss
from .model import initial_model
from .render import DeviceGaussians, Renderer, Tuning
from .render.backward import SumsLayout, project_backward, rasterize_backward, split_geometry
from .render.gaussians import group_widths
from .runtime import Runtime
from .scene.camera import Camera, Scene

RECIPE_ITERATIONS = 30_000   # the 3DGS schedule is written for this many iterations; shorter runs scale it
CHECKPOINT = "checkpoint.npz"
CONFIG = "config.json"
OUTPUT_SETTINGS = ("save_at", "checkpoint_every")   # TrainConfig fields that do not change the trained model


@dataclass(frozen=True)
class TrainConfig:
    scene: str
    iterations: int = RECIPE_ITERATIONS
    strategy: str = "3dgs"
    resolution: int | None = None
    test_every: int = 8
    white_background: bool = False
    seed: int = 0
    sh_degree: int = SH_MAX_DEGREE
    save_at: tuple[int, ...] = ()          # PLYs at these iterations (the last one is always saved)
    checkpoint_every: int = 1_000
    # learning rates (3DGS); the position's decays log-linearly over the run and scales with the extent
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    densify_until: int | None = None       # override the strategy's (scaled) window end; 0 disables densification
    low_memory: bool = False               # backward sums with float atomics, no per-pair slots (not bit-reproducible)
    # DC4GS (off unless dcc or dcs); see host/dc4gs.py
    dcc: bool = False
    dcs: bool = False
    dc_pooling: str = DC4GSConfig.pooling
    split_pick: str = DC4GSConfig.split_pick
    split_candidates: int | None = None    # DC4GSConfig.candidates, or DENSE_CANDIDATES with split_pick "dense"
    dcc_reading: str = DC4GSConfig.dcc_reading
    dcs_track: float = DC4GSConfig.track   # DCS: split costs only while the split criterion is >= this x threshold

    def __post_init__(self):
        problems = []
        if self.iterations < 1:
            problems.append(f"--iterations {self.iterations} must be at least 1")
        if self.strategy not in STRATEGIES:
            problems.append(f"--strategy {self.strategy!r} is not one of {', '.join(STRATEGIES)}")
        if any(s < 1 or s > self.iterations for s in self.save_at):
            problems.append(f"--save-at {list(self.save_at)} must lie in 1..{self.iterations}")
        if self.test_every < 0:
            problems.append(f"--test-every {self.test_every} must be 0 (no test views) or positive")
        if self.checkpoint_every < 1:
            problems.append(f"--checkpoint-every {self.checkpoint_every} must be at least 1")
        if self.densify_until is not None and self.densify_until < 0:
            problems.append(f"--densify-until {self.densify_until} must be >= 0")
        if not 0 <= self.sh_degree <= SH_MAX_DEGREE:
            problems.append(f"--sh-degree {self.sh_degree} must be 0..{SH_MAX_DEGREE}")
        try:   # checked whether or not DC4GS is on, so that a mistyped flag never passes silently
            self.dc4gs_settings()
        except ValueError as e:
            problems.append(str(e))
        if problems:
            raise InputError(None, "; ".join(problems))

    def dc4gs(self) -> DC4GSConfig | None:
        """The DC4GS settings, None when DC4GS is off."""
        return self.dc4gs_settings() if self.dcc or self.dcs else None

    def dc4gs_settings(self) -> DC4GSConfig:
        candidates = self.split_candidates or (DENSE_CANDIDATES if self.split_pick == "dense" else DC4GSConfig.candidates)
        return DC4GSConfig(dcc=self.dcc, dcs=self.dcs, pooling=self.dc_pooling, split_pick=self.split_pick,
                           candidates=candidates, dcc_reading=self.dcc_reading, track=self.dcs_track)

    @property
    def schedule_scale(self) -> float:
        return self.iterations / RECIPE_ITERATIONS

    def scaled(self, steps: int) -> int:
        """An iteration count of the 30,000-iteration recipe, scaled to this run's length."""
        return max(1, round(steps * self.schedule_scale))

    def to_json(self) -> dict:
        d = asdict(self)
        d["save_at"] = list(self.save_at)
        return d

    @staticmethod
    def from_json(d: dict) -> "TrainConfig":
        known = {f.name for f in fields(TrainConfig)}
        d = {k: v for k, v in d.items() if k in known}
        d["save_at"] = tuple(d.get("save_at", ()))
        return TrainConfig(**d)


MIN_DENSIFY_STEPS = 10   # a short run still densifies about this often


def make_strategy(cfg: TrainConfig) -> Strategy:
    """The strategy with its schedule scaled to the run's length (the recipe's numbers are for 30,000
    iterations). The interval between densification steps is not scaled, as the statistics need that
    many views and new Gaussians that many steps to settle (scaling it grows the model explosively);
    it shrinks only where fewer than MIN_DENSIFY_STEPS would fit in the window."""
    cls = STRATEGIES[cfg.strategy]
    base = cls.default_config()
    start, stop = cfg.scaled(base.densify_from), cfg.scaled(base.densify_until)
    every = min(base.densify_every, max(1, (stop - start) // MIN_DENSIFY_STEPS))
    c = replace(base, densify_from=start, densify_until=stop, densify_every=every,
                big_world_after=cfg.scaled(base.big_world_after),
                opacity_reset_every=cfg.scaled(base.opacity_reset_every),
                opacity_clamp_every=None if base.opacity_clamp_every is None else cfg.scaled(base.opacity_clamp_every))
    if cfg.densify_until is not None:
        c = replace(c, densify_until=cfg.densify_until)
    return cls(c, cfg.dc4gs())


@dataclass
class Progress:
    """What the progress bar shows; refreshed every few iterations."""
    loss: float = math.nan
    psnr: float = math.nan
    gaussians: int = 0


class Trainer:
    def __init__(self, cfg: TrainConfig, scene: Scene, rt: Runtime, out: Path):
        self.cfg, self.scene, self.rt, self.out = cfg, scene, rt, Path(out)
        if not scene.train:
            raise InputError(scene.root, "the scene has no training cameras")
        self.strategy = make_strategy(cfg)
        tuning = Tuning.for_device(rt.caps)
        self.renderer = Renderer(rt, replace(tuning, pair_sums=False) if cfg.low_memory else tuning)
        self.loss = Loss(rt)
        self.background = scene.background
        self.extent = scene.extent
        self.rng = np.random.default_rng(cfg.seed)
        self.iteration = 0
        self.camera_stack: list[int] = []
        self.stats_layout = self.strategy.sums_layout()
        self.plain_layout = SumsLayout()
        model = initial_model(scene.points, scene.colors, self.rng, cfg.sh_degree)
        self.params = DeviceGaussians(rt, model)
        self.widths = group_widths(self.params.sh_coeffs)
        self.adam = Adam(rt, self.widths, self.params.n)
        self.window = WindowStats(rt, self.stats_layout, self.extent, self.strategy.window_layout(),
                                  self.strategy.track_threshold)
        self.window.reset(self.params.n)
        self.progress = Progress(gaussians=self.params.n)
        self.target = rt.buffer(4)
        self.grad_image = rt.buffer(4)

    # schedules ----------------------------------------------------------------------------------------
    @property
    def sh_degree(self) -> int:
        """Active SH degree: one more every 1,000 (scaled) iterations, up to the model's."""
        return min(self.cfg.sh_degree, self.iteration // self.cfg.scaled(1_000))

    def learning_rates(self, skip_opacity: bool) -> dict:
        c = self.cfg
        lrs = {"means": exponential_lr(self.iteration, c.lr_means * self.extent, c.lr_means_final * self.extent,
                                       c.iterations),
               "log_scales": c.lr_scales, "quats": c.lr_quats, "opacity_logits": c.lr_opacity,
               "sh": (c.lr_sh_dc, c.lr_sh_rest)}
        if skip_opacity:
            del lrs["opacity_logits"]
        return lrs

    def next_camera(self) -> Camera:
        """A random training camera, each once per pass (the 3DGS camera stack)."""
        if not self.camera_stack:
            self.camera_stack = list(range(len(self.scene.train)))
        return self.scene.train[self.camera_stack.pop(int(self.rng.integers(len(self.camera_stack))))]

    # one iteration ------------------------------------------------------------------------------------
    def step(self) -> None:
        self.iteration += 1
        it, rt, s = self.iteration, self.rt, self.strategy
        cam = self.next_camera()
        target = self.scene.image(cam)
        nbytes = target.nbytes
        if self.target.size < nbytes:
            self.target, self.grad_image = rt.buffer(nbytes), rt.buffer(nbytes)
        rt.write(self.target, target)

        res = self.renderer.render(self.params, cam, self.sh_degree, self.background)
        self.loss(res.raster.image, self.target, cam.width, cam.height, self.grad_image)
        collecting = s.collecting(it)
        layout = self.stats_layout if collecting else self.plain_layout
        r = self.renderer
        geometry = split_geometry(rt, r.ws, self.params, cam, res, layout.split_candidates,
                                  s.config.percent_dense * self.extent,
                                  (self.window.buffer, self.window.layout.defines())) if layout.split_candidates else None
        sums = rasterize_backward(rt, r.ws, r.tuning, r.defines, layout, res, self.grad_image, self.background,
                                  geometry)
        if collecting:
            self.window.accumulate(res, sums, geometry)

        densify = s.densify_now(it)
        clamp = s.clamp_opacity_now(it)
        reset = s.reset_opacity_now(it, self.cfg.white_background)
        if not densify:         # 3DGS takes no optimiser step on a densification iteration: no gradients needed
            project_backward(rt, self.params, cam, self.sh_degree, res, sums, layout,
                             adam_step=self.adam.fused_step(self.learning_rates(skip_opacity=clamp or reset)))
        if it in self.cfg.save_at:   # before this iteration's densification and opacity reset, as Inria saves
            self.save_model()
        if densify:
            self.densify()
        if clamp:
            self.limit_opacity(s.config.opacity_clamp)
        if reset:
            self.limit_opacity(s.config.opacity_reset_to)

    def densify(self) -> None:
        gs = GaussianSet(self.params.download(), self.adam.m.download(), self.adam.v.download())
        self.strategy.densify(gs, self.window.download(), self.iteration, self.extent, self.rng)
        self.load_set(gs)
        self.window.reset(gs.n)

    def load_set(self, gs: GaussianSet) -> None:
        self.params.upload(gs.params)
        self.adam.m.upload(gs.m)
        self.adam.v.upload(gs.v)
        self.progress.gaussians = gs.n

    def limit_opacity(self, ceiling: float) -> None:
        """Opacities above the ceiling drop to it; the opacities' Adam moments restart (3DGS reset, AbsGS clamp)."""
        logits = self.params.download_group("opacity_logits")
        limit = math.log(ceiling / (1 - ceiling))
        self.params.upload_group("opacity_logits", np.minimum(logits, limit))
        zeros = np.zeros_like(logits)
        self.adam.m.upload_group("opacity_logits", zeros)
        self.adam.v.upload_group("opacity_logits", zeros)

    # checkpoints --------------------------------------------------------------------------------------
    def save_checkpoint(self) -> None:
        arrays = {f"param/{k}": v for k, v in self.params.download().items()}
        arrays |= {f"m/{k}": v for k, v in self.adam.m.download().items()}
        arrays |= {f"v/{k}": v for k, v in self.adam.v.download().items()}
        arrays |= {f"window/{k}": v for k, v in self.window.download().items()}
        meta = {"iteration": self.iteration, "config": self.cfg.to_json(), "adam_steps": self.adam.steps,
                "rng": self.rng.bit_generator.state, "camera_stack": self.camera_stack,
                "train_cameras": [c.name for c in self.scene.train], "gaussians": self.params.n}
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)

        def write(tmp):
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
        write_atomic(self.out / CHECKPOINT, write)

    def load_checkpoint(self, path: Path) -> None:
        try:
            with np.load(path) as f:
                data = {k: f[k] for k in f.files}
            meta = json.loads(bytes(data.pop("meta")).decode())
            saved = TrainConfig.from_json(meta["config"])
            group = lambda prefix: {k.split("/", 1)[1]: v for k, v in data.items() if k.startswith(prefix + "/")}
            params, m, v, window = group("param"), group("m"), group("v"), group("window")
        except (OSError, ValueError, KeyError, json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(path, f"corrupt checkpoint ({e.__class__.__name__}: {e})") from None
        mismatched = [f.name for f in fields(TrainConfig)
                      if f.name not in OUTPUT_SETTINGS and getattr(saved, f.name) != getattr(self.cfg, f.name)]
        if mismatched:
            diffs = ", ".join(f"{k}: checkpoint {getattr(saved, k)!r} vs now {getattr(self.cfg, k)!r}" for k in mismatched)
            raise InputError(path, f"checkpoint is from other settings ({diffs})")
        if meta["train_cameras"] != [c.name for c in self.scene.train]:
            raise InputError(path, "checkpoint was made with other training images")
        n = meta["gaussians"]
        if set(params) != set(self.widths) or any(a.shape != (n, self.widths[k]) for k, a in params.items()):
            raise InputError(path, "checkpoint arrays do not match the model layout")
        self.load_set(GaussianSet(params, m, v))
        self.window.upload(window)
        self.adam.steps = meta["adam_steps"]
        self.rng.bit_generator.state = meta["rng"]
        self.camera_stack = meta["camera_stack"]
        self.iteration = meta["iteration"]

    # outputs ------------------------------------------------------------------------------------------
    def save_model(self) -> Path:
        from .ply import write_ply
        path = self.out / "point_cloud" / f"iteration_{self.iteration}" / "point_cloud.ply"
        write_ply(path, self.params.download_model())
        return path

    def run(self, progress: bool = True, log_every: int = 10) -> None:
        """Train to cfg.iterations; Ctrl-C (SIGINT) stops at the next iteration boundary after a checkpoint."""
        from tqdm import tqdm
        stop = {"now": False}
        previous = signal.signal(signal.SIGINT, lambda *_: stop.update(now=True)) \
            if threading_main() else None
        bar = tqdm(total=self.cfg.iterations, initial=self.iteration, disable=not progress, dynamic_ncols=True,
                   unit="it")
        try:
            while self.iteration < self.cfg.iterations:
                if stop["now"]:
                    self.save_checkpoint()
                    raise KeyboardInterrupt
                self.step()
                bar.update(1)
                if self.iteration % self.cfg.checkpoint_every == 0:
                    self.save_checkpoint()
                if self.iteration % log_every == 0 or self.iteration == self.cfg.iterations:
                    stats = self.loss.read_stats()
                    self.progress.loss = stats["loss"]
                    self.progress.psnr = 10 * math.log10(1 / max(stats["mse"], 1e-12))
                    bar.set_postfix(loss=f"{self.progress.loss:.4f}", psnr=f"{self.progress.psnr:.2f}",
                                    gaussians=f"{self.progress.gaussians:,}", refresh=False)
            self.save_model()
            self.save_checkpoint()
        finally:
            bar.close()
            if previous is not None:
                signal.signal(signal.SIGINT, previous)


def threading_main() -> bool:
    import threading
    return threading.current_thread() is threading.main_thread()


RUN_FILES = (CONFIG, "cfg_args", "cameras.json", CHECKPOINT, "results.json", "per_view.json")
RUN_DIRS = ("point_cloud", "test")


def holds_run(out: Path) -> bool:
    return any((out / f).exists() for f in RUN_FILES + RUN_DIRS)


def clear_run(out: Path) -> None:
    """Remove a previous run's files (only ours: anything else in the folder stays)."""
    import shutil
    for f in RUN_FILES:
        (out / f).unlink(missing_ok=True)
    for d in RUN_DIRS:
        shutil.rmtree(out / d, ignore_errors=True)


def write_run_files(out: Path, cfg: TrainConfig, scene: Scene) -> None:
    """The settings (config.json, and cfg_args as the Inria tools read it) and cameras.json."""
    write_json(out / CONFIG, cfg.to_json())
    cfg_args = (f"Namespace(sh_degree={cfg.sh_degree}, source_path={str(scene.root.resolve())!r}, "
                f"model_path={str(out.resolve())!r}, images='images', resolution={cfg.resolution or -1}, "
                f"white_background={cfg.white_background}, data_device='cuda', eval={cfg.test_every > 0})")
    write_atomic(out / "cfg_args", lambda tmp: tmp.write_text(cfg_args))
    cams = [{"id": i, "img_name": Path(c.name).stem, "width": c.width, "height": c.height,
             "position": c.center.tolist(), "rotation": c.R.T.tolist(), "fy": c.fy, "fx": c.fx}
            for i, c in enumerate(scene.train + scene.test)]
    write_json(out / "cameras.json", cams)
