"""The training loop: the 3DGS recipe on the device, the host owning the schedules, Adam's logic and the
density control (a strategy, densify/); checkpoints through the run folder, so that an interrupted
run resumes to the same model.

One iteration (docs/architecture.md draws it module by module):
    render (render/) -> loss and dL/dimage (backward/loss.py; with --exposure, of the render corrected by its
    photo's affine, backward/exposure.py, which steps the corrections) -> what the strategy gathers this view and
    where it folds it (plain data; its split geometry, for DCS) -> rasterizer backward into per-Gaussian sums
    (backward/), the view's statistics folded into the strategy's window on the way -> projection backward
    with Adam's step fused in, where the recipe steps (a batch: each view's gradients added, one step on their
    mean) -> the strategy's step after it (MCMC's position noise) -> the strategy densifies and limits opacities
    where its schedule says.
Per iteration the host queues everything, the target image's upload included, and then waits once, for the view's
counts alone (visible Gaussians, pairs: render/isect.py; Gaussians spanning the backward's runs: backward/), read as
soon as they are final, before the loss: the device runs the loss and the backward while the host goes on to the
next iteration. Buffers are sized by a pair capacity and carry rows; a view with more runs again with room (step).
The loss is read every few iterations for the metrics file and the progress display (log.py).
"""
from __future__ import annotations

import signal
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..backward import ProjectBackward, RasterizeBackward
from ..backward.exposure import Exposure, colour_coordinates
from ..backward.loss import STAT_KEYS, Loss
from ..config import DEFAULT_LINE_EVERY, TrainConfig
from ..densify import Actions, Strategy
from ..errors import DeviceError, InputError
from ..model import GaussianSet, initial_model
from ..optim.adam import one_group_step
from ..optim.batch_gradients import BatchGradients, batch_adam_config
from ..optim.trainable import TrainableGaussians
from .parallel import SingleProcess
from ..render import DeviceGaussians, Renderer, RenderOptions, Tuning
from ..render.stage import FrameCounts
from ..run_folder import Checkpoint, RunFolder, TrainingState
from ..runtime import BUFFER_HEADROOM, Runtime, describe
from ..scene.camera import Camera, Scene
from .log import SAMPLE_EVERY, TrainingLog
from .schedule import Schedule

# SIGUSR1 too: MPI launchers forward it untouched, where SIGTERM and SIGINT make Open MPI's mpirun kill its
# processes a quarter of a second later (Slurm's --signal=USR1@SECONDS sends it ahead of a job's time limit)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1)


class Stopped(KeyboardInterrupt):
    """Training stopped by a signal after writing a checkpoint; the process should exit 128 + signum."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class Trainer:
    def __init__(self, cfg: TrainConfig, scene: Scene, rt: Runtime, out: str | Path | RunFolder | None = None,
                 strategy: Strategy | None = None, check_finite: bool = False, frozen: bool = False,
                 lpips: tuple = (None, ""), group: SingleProcess | None = None):
        """out: the run folder, which checkpoints, saved models and run() need (None: none, for a trainer that
        only steps); strategy: the density control (default: the configuration's, its schedule scaled to the
        run); check_finite: every stage checks its outputs and the first NaN or Inf stops the run (finite.py);
        frozen: the strategy gathers its statistics but never densifies nor limits opacities, so that
        benchmarks step the same model again and again; lpips: metrics.lpips_metric's (network, note), for the
        test-view evaluations (default none); group: the processes training together (parallel.py; default this
        one alone), of which process 0 writes the run folder."""
        if not scene.train:
            raise InputError(scene.root, "the scene has no training cameras")
        if rt.caps.loop_limit:   # runtime.LOOP_LIMITED_DRIVERS: its renders are right, its gradients of busy views not
            raise DeviceError(f"{describe(rt.device)} cuts every work-item's loops short after {rt.caps.loop_limit:,} "
                              "iterations (llvmpipe's loop limiter, removed in Mesa 25.0), which leaves the gradients "
                              "of busy views wrong: train on another device (see `dc4gs-cl devices`; PoCL comes with "
                              "dc4gs-cl) or with Mesa 25 or later. Rendering and eval work on it.")
        self.group = group or SingleProcess()
        if cfg.batch % self.group.size:
            raise InputError(None, f"--batch {cfg.batch} must be a multiple of the {self.group.size} processes (each "
                                   "renders the same number of a batch's views)")
        self.cfg, self.scene, self.rt = cfg, scene, rt
        self.run_folder = out if isinstance(out, RunFolder) or out is None else RunFolder(out)
        self.frozen = frozen
        self.lpips, self.lpips_note = lpips
        self.schedule = Schedule(cfg)
        tuning = Tuning.for_device(rt.caps)
        if cfg.low_memory:   # float-atomic sums instead of per-pair slots
            tuning = replace(tuning, pair_sums=False)
        self.renderer = Renderer(rt, tuning, RenderOptions(antialiased=cfg.antialiased), check_finite=check_finite)
        self.context = self.renderer.context
        self.loss = Loss(self.context, lambda_dssim=cfg.lambda_dssim)
        self.rasterize_backward = RasterizeBackward(self.context)
        self.project_backward = ProjectBackward(self.context)
        # --exposure: a correction per training photo (index: its place in scene.train) and this iteration's step
        # (its Adam counts the means' steps: once an iteration, however often a view runs)
        self.exposure = None if not cfg.exposure else Exposure(
            self.context, len(scene.train),
            coords=colour_coordinates((scene.image(cam), scene.mask(cam)) for cam in scene.train))
        self.photo_index = {cam.name: i for i, cam in enumerate(scene.train)}
        self.exposure_step = one_group_step(0.0, 0)
        self.rng = np.random.default_rng(cfg.seed)
        self.iteration = 0
        self.camera_stack: list[int] = []
        self.pair_capacity = 0   # the pairs a view's buffers hold; grows when a view has more (step)
        self.carry_rows = 0      # the backward's carry rows, for Gaussians whose pairs span its runs (likewise)
        self.strategy = strategy or self.schedule.strategy()
        initial = initial_model(scene.points, scene.colors, self.rng, cfg.sh_degree, **self.strategy.initial)
        if cfg.max_gaussians is not None and len(initial) > cfg.max_gaussians:
            raise InputError(None, f"--max-gaussians {cfg.max_gaussians:,} is below the {len(initial):,} Gaussians the "
                                   "scene starts from (one per SfM point)")
        self.model = TrainableGaussians(rt, initial, batch_adam_config(cfg.batch))
        self.batch = BatchGradients(self.context, self.model.widths) if cfg.batch > 1 else None
        self.actions = Actions()   # the last iteration's
        self.strategy.attach(self.context, scene.extent, self.model.n, cfg.white_background)
        self.strategy.reduce_window = self.group.reduce_window
        self.log: TrainingLog | None = None   # while run() runs, and after it for the final evaluation
        if (cap := self.cap) is not None and cap * self.held_bytes_per_gaussian() > rt.device.global_mem_size:
            # MCMC grows to its cap: --max-gaussians 1000000000 was taken and grew to 4.1 GB by iteration 120
            raise InputError(None, f"--max-gaussians {cap:,}: {self.cap_memory(rt)}, more than this device holds")

    @property
    def cap(self) -> int | None:
        """The most Gaussians the density control grows the model to (None: no cap)."""
        return self.strategy.config.max_gaussians

    def held_bytes_per_gaussian(self) -> int:
        """Device bytes a Gaussian holds whatever the view: its parameters, Adam's two moments and the window's
        statistics (float32). A training view adds its pairs' and images' buffers: the peak measured by bench is
        1.0 to 1.8 KB a Gaussian (README)."""
        return 4 * (3 * sum(self.model.widths.values()) + sum(self.strategy.statistics.window.widths().values()))

    def cap_memory(self, rt: Runtime) -> str:
        """What the cap means in memory on rt's device, in words."""
        need = self.cap * self.held_bytes_per_gaussian()
        return (f"its parameters, moments and statistics alone take {need / 2**30:.1f} GiB of the device's "
                f"{rt.device.global_mem_size / 2**30:.1f} GiB (training's peak: about 1 to 1.8 KB a Gaussian)")

    @property
    def params(self) -> DeviceGaussians:
        return self.model.params

    @property
    def sh_degree(self) -> int:
        return self.schedule.sh_degree(self.iteration)

    def next_camera(self) -> Camera:
        """A random training camera, each once per pass (the 3DGS camera stack)."""
        if not self.camera_stack:
            self.camera_stack = list(range(len(self.scene.train)))
        return self.scene.train[self.camera_stack.pop(int(self.rng.integers(len(self.camera_stack))))]

    # one iteration ------------------------------------------------------------------------------------
    def step(self) -> None:
        """One iteration: one view (the model stepped by its gradients, fused into their computation), or with
        --batch B, B views (the model stepped by their mean; optim/batch_gradients.py)."""
        self._queue_iteration()
        # before this iteration's densification and opacity limits, as Inria saves
        if self.iteration in self.cfg.save_at:
            self.save_model()
        if self.strategy.apply(self.actions, self.iteration, self.model, self.rng) is not None:
            if self.context.check.enabled:
                self.context.check("densify", self.model.download().params)

    def _queue_iteration(self) -> None:
        """Queue an iteration up to its densification: its views, each queued until it fits (_queue_fitting), and
        where the actions say, the optimiser step, then the strategy's after it (queued after the last view's wait:
        the device still has that view's loss and backward to run). With a batch, this process's share of its views,
        each view's gradients added to the batch's, the processes' sums added, then one step on their mean; every
        process draws every view of the batch, so that all keep the same generator."""
        self.iteration += 1
        it = self.iteration
        views = [(self.next_camera(), self._background()) for _ in range(self.cfg.batch)]
        self.actions = Actions() if self.frozen else self.strategy.actions(it)
        step_args = None   # the optimiser's Adam step (counted once, however often a view runs), moments, regularisers
        if self.actions.optimiser_step:
            lrs = self.schedule.learning_rates(it, self.scene.extent, self.actions.opacity_steps)
            adam = self.model.adam
            step_args = (adam.step_value(lrs), adam.m, adam.v, self.strategy.regularizers(self.model.n))
        if self.exposure is not None:   # the corrections step where the Gaussians' means do (t = 0: no step)
            t = self.model.adam.steps["means"] if self.actions.optimiser_step else 0
            self.exposure_step = one_group_step(self.schedule.exposure_lr(it), t)
        summed = None if self.batch is None else self.batch.start(self.model.n)
        for cam, background in self.group.share(views):
            self._queue_fitting(it, cam, background, step_args, summed)
        if step_args is not None:
            if summed is not None:
                self.group.sum_gradients(self.batch.sums)
                self.batch.step(self.params, self.cfg.batch, *step_args)
            self.strategy.after_step(it, self.params, lrs, self.cfg.seed)

    def _queue_fitting(self, it: int, cam: Camera, background: np.ndarray, step_args: tuple | None,
                       summed: dict | None) -> None:
        """Queue a view (_queue_view) and wait for its counts alone, read as soon as they are final, before the loss
        (the device runs the rest of the view while the host goes on): a view whose pairs overflowed the capacity it
        was given (render/isect.py), or whose Gaussians spanning the backward's runs its carry rows
        (RasterizeBackward.plan), changed nothing on the device (kernels/common.h FRAME_VOID), and runs again with
        room for them, the loss' call count (the one host state a view changes) rewound."""
        calls = self.loss.calls
        while self._overflowed(self._queue_view(it, cam, background, step_args, summed)):
            self.loss.calls = calls

    def _background(self) -> np.ndarray:
        """A view's background: --random-background draws a colour from the run's generator (the Inria code's,
        gsplat's random_bkgd: transparent regions cost loss on every view, whatever the target's background)."""
        return self.rng.random(3).astype(np.float32) if self.cfg.random_background else self.scene.background

    def _overflowed(self, read: FrameCounts) -> bool:
        """Wait for a view's counts (the iteration's one blocking read); where they overflowed its buffers, make
        room for them and say so (the view changed nothing: it runs again)."""
        counts = read.result()
        if not counts["OVERFLOWED"]:
            return False
        if counts["PAIRS"] > self.pair_capacity:
            self.pair_capacity = int(counts["PAIRS"] * (1 + BUFFER_HEADROOM))
        if counts["SPANNING"] > self.carry_rows:
            self.carry_rows = int(counts["SPANNING"] * (1 + BUFFER_HEADROOM))
        return True

    def _queue_view(self, it: int, cam: Camera, background: np.ndarray, step_args: tuple | None,
                    summed: dict | None) -> FrameCounts:
        """Queue a view of iteration it: the render, the loss, what the strategy gathers, the rasterizer backward
        and, where the iteration steps (step_args: ProjectBackward.step's Adam step, moments and regularisers), the
        projection backward: Adam's step fused in, or with a batch (summed: its sums' buffers) the view's gradients
        added to the batch's. Nothing is read back (the view's counts are queued for reading: returned)."""
        rt, s, ws = self.rt, self.strategy, self.context.ws
        self.context.check.at = f"iteration {it}"
        target, keep = self.scene.image(cam), self.scene.mask(cam)
        target_buf, dL_dimage = ws.get("train.target", target.nbytes), ws.get("train.dL_dimage", target.nbytes)
        keep_buf = None
        if keep is not None:   # masked pixels: no loss, no gradient, no statistic (loss.cl, rasterize_backward.cl)
            keep_buf = ws.get("train.keep", keep.size)
            rt.write_async(keep_buf, keep)   # bool: one byte, 0 or 1, as the kernels' uchar
        rt.write_async(target_buf, target)   # the scene keeps its images as decoded: nothing to wait for

        # --check-finite reads each stage's outputs as it goes: the view sized exactly, so that none is left void
        capacity = None if self.context.check.enabled else self.pair_capacity
        res = self.renderer.render(self.params, cam, self.sh_degree, background, capacity)
        gathering = s.gather(it, self.params, cam, res)
        # before the loss: a view that needs more carry rows is void before any lasting state changes
        plan = self.rasterize_backward.plan(res, gathering.layout, gathering.window,
                                            None if capacity is None else self.carry_rows)
        counts = self.context.frame_counts_later()   # final from here on: no later kernel counts or overflows
        image, pixels = res.raster.image, cam.width * cam.height
        if self.exposure is not None:   # the loss sees the corrected render; its gradient goes back through A^T
            image = self.exposure.apply(image, self.photo_index[cam.name], pixels)
        self.loss(image, target_buf, cam.width, cam.height, dL_dimage, keep=keep_buf,
                  kept=np.count_nonzero(keep) if keep is not None else 0)
        if self.exposure is not None:
            self.exposure.backward(res.raster.image, dL_dimage, self.photo_index[cam.name], pixels,
                                   self.exposure_step, keep_buf)
        sums, layout = self.rasterize_backward.folding(res, dL_dimage, background, gathering.layout,
                                                       gathering.geometry, keep_buf, gathering.window, plan)
        if step_args is not None and summed is None:
            self.project_backward.step(self.params, cam, self.sh_degree, res, sums, layout, *step_args)
        elif step_args is not None:
            self.project_backward.gradients(self.params, cam, self.sh_degree, res, sums, layout, summed,
                                            accumulate=True)
        return counts

    def start_from(self, gs: GaussianSet, iteration: int) -> None:
        """Continue from these Gaussians (parameters and moments) at this iteration, the window restarted
        (benchmarks start their configurations from one trained state this way)."""
        self.model.upload(gs)
        self.strategy.reset(gs.n)
        self.iteration = iteration

    def memory_held(self) -> dict[str, int]:
        """Device bytes held now, by what holds them (capacity included)."""
        m = self.model
        return {"parameters": m.params.nbytes, "Adam m": m.adam.m.nbytes, "Adam v": m.adam.v.nbytes,
                **self.strategy.memory_held(), **self.context.ws.held()}

    # checkpoints --------------------------------------------------------------------------------------
    def _folder_for(self, purpose: str) -> RunFolder:
        """The run folder, which `purpose` needs."""
        if self.run_folder is None:
            raise RuntimeError(f"{purpose} needs a run folder, and this trainer was made without one (out=None)")
        return self.run_folder

    def save_checkpoint(self) -> None:
        """Write a checkpoint (process 0). In a parallel run every process calls this together: the processes'
        windows are summed into process 0's (the others' restart at zero, so that a run resumed from it, with any
        process count, goes on from the same state), and their models are checked to be the same."""
        gs = self.model.download()
        window = self.strategy.checkpoint_state()
        if self.group.size > 1:
            self.strategy.restore_state(window, holder=self.group.rank == 0)
            self.group.check_same(gs.params, f"iteration {self.iteration}")
        if not self.group.writes:
            return
        state = TrainingState(config=self.cfg, params=gs.params, m=gs.m, v=gs.v,
                              window=window, iteration=self.iteration,
                              adam_steps=self.model.adam.steps, rng=self.rng.bit_generator.state,
                              camera_stack=self.camera_stack, train_cameras=[c.name for c in self.scene.train],
                              # so that the first metrics sample after --resume is the same
                              loss_sums=self.loss.running_sums(),
                              exposure=None if self.exposure is None else self.exposure.download())
        folder = self._folder_for("a checkpoint")
        folder.write_checkpoint(*state.entries())
        if self.exposure is not None:   # for inspection: what the corrections are now
            folder.write_exposure(self.iteration, list(self.photo_index), state.exposure["T"])

    def resume(self) -> Checkpoint:
        """Continue from the run folder's newest intact checkpoint (returned: which file, and the corrupt ones
        passed over), which must come from these settings and images."""
        checkpoint = self._folder_for("resuming").read_checkpoint()
        state, path = checkpoint.training_state(len(STAT_KEYS)), checkpoint.path
        if diffs := state.config.differences(self.cfg):
            raise InputError(path, "checkpoint is from other settings (" + ", ".join(
                f"{k}: checkpoint {a!r} vs now {b!r}" for k, (a, b) in diffs.items()) + ")")
        if state.train_cameras != [c.name for c in self.scene.train]:
            raise InputError(path, "checkpoint was made with other training images")
        try:
            self.model.upload(GaussianSet(state.params, state.m, state.v))
        except (ValueError, KeyError):
            raise InputError(path, "checkpoint arrays do not match the model layout") from None
        self.strategy.restore_state(state.window, holder=self.group.rank == 0)   # a parallel run's: process 0's
        self.model.adam.steps = state.adam_steps
        self.rng.bit_generator.state = state.rng
        self.camera_stack = state.camera_stack
        self.iteration = state.iteration
        if state.loss_sums is not None:
            self.loss.restore_sums(*state.loss_sums)
        if self.exposure is not None:
            try:
                self.exposure.upload(state.exposure)
            except (ValueError, TypeError):   # TypeError: none at all
                raise InputError(path, "checkpoint holds no exposure corrections of these training photos") from None
        return checkpoint

    # outputs ------------------------------------------------------------------------------------------
    def save_model(self) -> Path:
        """Write the model at this iteration (process 0; the others' path only)."""
        folder = self._folder_for("saving a model")
        if not self.group.writes:
            return folder.model_path(self.iteration)
        return folder.save_model(self.iteration, self.params.download_model())

    def evaluate_test(self, render_dir: Path | None = None) -> dict:
        """Evaluate the test views now (evaluate.evaluate; with render_dir, their PNGs too) and log it; the
        training clock and the per-stage times leave the evaluation out."""
        from ..evaluation.evaluate import evaluate
        log = self.log
        if log is not None:
            log.pause()
        result = evaluate(self.rt, self.renderer, self.params, self.scene, self.scene.test, self.sh_degree, render_dir,
                          self.lpips, self.lpips_note, self.cfg.corrected_metrics)
        if self.rt.profiling:
            self.rt.stage_times()   # the evaluation's renders are not training time
        if log is not None:
            log.evaluation(self.iteration, result)
            log.resume()
        return result

    def run(self, progress: str = "bar", line_every: int = DEFAULT_LINE_EVERY, viewer=None) -> None:
        """Train to cfg.iterations, evaluating the test views at the schedule's evaluation points before the
        last (the caller evaluates the last, with renders), and logging to the run folder's metrics file.
        progress: "bar", "lines" (one every line_every iterations) or "none" (train/log.py). Ctrl-C (SIGINT),
        SIGTERM (what job schedulers send) or SIGUSR1 stops at the next iteration boundary after a checkpoint,
        raising Stopped. viewer: a viewer.Viewer shown the model between iterations (live training)."""
        run_folder = self._folder_for("run() (its metrics file, checkpoints and model)")
        stop = {"signal": None}
        main_thread = threading.current_thread() is threading.main_thread()
        previous = {sig: signal.signal(sig, lambda signum, _: stop.update(signal=signum))
                    for sig in STOP_SIGNALS} if main_thread else {}
        writes = self.group.writes   # a parallel run's other processes log nothing and evaluate nothing
        self.log = TrainingLog(run_folder if writes else None, self.cfg.iterations, self.iteration,
                               progress if writes else "none", line_every,
                               self.rt.stage_times if self.rt.profiling else None)
        evaluate_at = ({i for i in self.schedule.evaluations() if i < self.cfg.iterations}
                       if self.scene.test and writes else set())
        try:
            while self.iteration < self.cfg.iterations:
                if self.group.any(stop["signal"] is not None):   # every process stops at the same iteration
                    self.save_checkpoint()
                    raise Stopped(stop["signal"] or signal.SIGTERM)
                self.step()
                self.log.step()
                if viewer is not None:   # returns at once while no browser is connected
                    viewer.publish(self.params, self.sh_degree, self.iteration,
                                   stopping=lambda: stop["signal"] is not None)
                if self.iteration % SAMPLE_EVERY == 0 or self.iteration == self.cfg.iterations:
                    stats = self.loss.read_stats()
                    self.log.sample(self.iteration, stats["loss"], stats["mse"], self.model.n)
                if self.iteration in evaluate_at:
                    self.evaluate_test()
                if self.iteration % self.cfg.checkpoint_every == 0:
                    self.save_checkpoint()
            self.save_model()
            self.save_checkpoint()
        finally:
            self.log.close()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
