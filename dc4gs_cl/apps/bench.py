"""`dc4gs-cl bench`: the benchmark a user runs on their own device and posts.

A fixed, versioned suite (SUITE_VERSION; change it whenever what is measured changes, so that reports of
different suites are never compared line by line):
- the built-in scene at two sizes: a model trained WARM iterations (3DGS, the built-in run's schedule) at the
  smaller size, then its forward (per stage, over FORWARD_VIEWS training views) and a training iteration per
  stage (3DGS, and AbsGS with DC4GS), at both sizes;
- a synthetic frame of a million random Gaussians (SH degree 3) at 1280 x 720: forward and training iteration;
- with `--garden PATH` (gsplat's test asset, test_garden.npz): its Gaussians as gsplat's tests make them, SH degree 3,
  at 648 x 420 over its 3 cameras: forward and training iteration;
- peak device bytes per Gaussian while training (the high-water mark of the bytes held in device buffers
  during the training iterations, over the Gaussian count; in the small scenes the images dominate, the
  million-Gaussian frame is the figure that counts);
- each stage's error against the float64 references (dc4gs_cl/reference) on a small random case.

Times are medians over ROUNDS rounds of OpenCL profiling events (device ms per stage) and of the wall clock;
beside them, per frame or iteration, the host ms (wall less device), the kernel launches, the blocking host
syncs and the kernel arguments set (Runtime.launches, syncs, arguments_set).
With `--gsplat` (torch and gsplat importable, with CUDA), every case's frames also run through gsplat
(apps/gsplat_frames.py): its forward and its simple_trainer iteration (absgrad off beside our 3DGS, on beside our
AbsGS + DC4GS), each case's ours / gsplat wall-time ratio, and its image against ours (PSNR: the same frame).
The training iterations gather densification statistics but never densify, so every round steps the same
model. Writes bench-<device>.json and .md (--out) and prints the markdown; `--compare A.json B.json` prints
B against A line by line.
"""
from __future__ import annotations

import gc
import json
import os
import platform
import re
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyopencl as cl

from .. import __version__
from ..backward import ProjectBackward, RasterizeBackward
from ..backward.loss import Loss
from ..config import TrainConfig
from ..densify import DC4GSConfig
from ..errors import InputError, OutputError
from ..files import write_atomic, write_json
from ..model import GaussianModel, GaussianSet, group_widths
from ..reference import loss as loss_reference
from ..reference.isect import intersect_reference
from ..reference.project import project_backward_reference, project_reference
from ..reference.rasterize import rasterize_backward_reference, rasterize_reference, undecided_pixels
from ..render import DeviceGaussians, Renderer
from ..runtime import Capabilities, Runtime, describe
from ..scene.builtin import builtin_scene
from ..scene.camera import Camera, Scene
from ..statistics import GRADIENTS
from ..reference.testing import gsplat_test_garden, random_camera, random_model
from ..train import Trainer
from ..train.schedule import Schedule

# 2: launches, blocking syncs and host ms per frame or iteration; 3: the GPU sort and the host loop of #39, --garden,
# --gsplat; 4: kernel arguments set (only those that changed since the kernel's last launch)
SUITE_VERSION = 4
# per frame or iteration, beside the times (timed_rounds): the quantity and its row in the reports
COUNTS = {"host_ms": "host ms (wall - device)", "launches": "kernel launches", "syncs": "blocking host syncs",
          "arguments": "kernel arguments set"}


@dataclass(frozen=True)
class Suite:
    builtin_sizes: tuple[tuple[int, int], ...] = ((192, 144), (384, 288))
    warm_iterations: int = 600        # of the built-in run's 5,000-iteration schedule: 27,960 Gaussians
    schedule: int = 5_000
    synthetic_gaussians: int = 1_000_000
    synthetic_size: tuple[int, int] = (1280, 720)
    rounds: int = 5
    iterations: int = 10              # training iterations per round (built-in scene)
    synthetic_iterations: int = 2     # training iterations per round (million Gaussians: seconds each)
    forward_views: int = 4
    accuracy_case: tuple[int, int, int] = (2500, 120, 90)   # Gaussians, width, height
    seed: int = 20261123


FULL = Suite()
QUICK = Suite(builtin_sizes=((48, 36), (96, 72)), warm_iterations=40, synthetic_gaussians=20_000,
              synthetic_size=(160, 90), rounds=2, iterations=2, synthetic_iterations=1, forward_views=2,
              accuracy_case=(300, 48, 40))
TRAINING = {"3dgs": {"strategy": "3dgs"},
            "absgs+DC4GS": {"strategy": "absgs", "dc4gs": DC4GSConfig(dcc=True, dcs=True)}}
# gsplat's nearest configuration to each of TRAINING: absgrad (AbsGS) or not (gsplat has no DC4GS)
GSPLAT_ABSGRAD = {"3dgs": False, "absgs+DC4GS": True}
GARDEN_AT = 3_000   # iteration of the 30,000 schedule the synthetic and garden frames train at: SH 3, in the window


def median(values) -> float:
    return float(np.median(values))


def frozen_trainer(cfg: TrainConfig, scene: Scene, rt: Runtime, state: GaussianSet, iteration: int,
                   closed: bool = False, split_costs_for_all: bool = False) -> Trainer:
    """A trainer holding `state` at `iteration` that gathers densification statistics but never densifies nor
    resets opacities, so benchmarks step the same model again and again. closed: no statistics either (an
    iteration after the densification window); split_costs_for_all: DC4GS split costs for every visible
    Gaussian, not only those large enough to split."""
    scaled = Schedule(cfg).strategy()
    c = scaled.config
    strategy = type(scaled).for_run(replace(c, densify_until=0 if closed else c.densify_until,
                                            percent_dense=0.0 if split_costs_for_all else c.percent_dense), cfg)
    trainer = Trainer(cfg, scene, rt, strategy=strategy, frozen=True)
    trainer.start_from(state, iteration)
    return trainer


def timed_rounds(rt: Runtime, rounds: int, per: int, work) -> dict:
    """`work()` (per frames or iterations) run `rounds` times: per frame or iteration, the median device ms of
    each stage and in all (OpenCL profiling events), the median wall ms, the host ms (wall less device: the
    host's own time and its waits), the kernel launches, blocking host syncs and kernel arguments set
    (Runtime.launches, syncs, arguments_set)."""
    rt.stage_times()
    times, walls = [], []
    launches, syncs, arguments = rt.launches, rt.syncs, rt.arguments_set
    for _ in range(rounds):
        start = time.perf_counter()
        work()
        times.append(rt.stage_times())     # waits for the queue
        walls.append(time.perf_counter() - start)
    stages = list(dict.fromkeys(s for r in times for s in r))
    device, wall = median([sum(r.values()) for r in times]) * 1e3 / per, median(walls) * 1e3 / per
    return {"stages_ms": {s: median([r.get(s, 0.0) for r in times]) * 1e3 / per for s in stages},
            "device_ms": device, "wall_ms": wall, "host_ms": wall - device,
            "launches": (rt.launches - launches) / (rounds * per), "syncs": (rt.syncs - syncs) / (rounds * per),
            "arguments": (rt.arguments_set - arguments) / (rounds * per)}


def time_forward(rt: Runtime, model: GaussianModel, cams: list[Camera], background, suite: Suite) -> dict:
    renderer, g = Renderer(rt), DeviceGaussians(rt, model)
    for cam in cams:                       # builds kernels and sizes buffers outside the timing
        res = renderer.render(g, cam, model.sh_degree, background)

    def frames():
        for cam in cams:
            renderer.render(g, cam, model.sh_degree, background)

    return {**timed_rounds(rt, suite.rounds, len(cams), frames), "pairs": int(res.isect.n_pairs)}


def time_training(rt: Runtime, cfg: TrainConfig, scene: Scene, state: GaussianSet, iteration: int,
                  suite: Suite, iterations: int) -> dict:
    gc.collect()                           # the previous trainer's buffers go before the peak restarts
    before = rt.memory_in_use
    rt.reset_memory_peak()
    trainer = frozen_trainer(cfg, scene, rt, state, iteration)
    for _ in scene.train:                  # builds kernels and sizes buffers (the pair room, the carry rows) for
        trainer.step()                     # every view outside the timing, so that no timed view runs twice

    def steps():
        for _ in range(iterations):
            trainer.step()

    out = timed_rounds(rt, suite.rounds, iterations, steps)
    peak = rt.memory_peak - before
    return {**out, "peak_bytes": int(peak), "bytes_per_gaussian": peak / state.n}


def training_config(name: str, scene: str, iterations: int) -> TrainConfig:
    return TrainConfig(scene=scene, iterations=iterations, **TRAINING[name])


def builtin_cases(rt: Runtime, suite: Suite, say) -> list[dict]:
    """The built-in scene: one model trained at the first size, measured at every size."""
    scenes = [builtin_scene(base_size=size) for size in suite.builtin_sizes]
    say(f"training the built-in scene {suite.warm_iterations} iterations at {suite.builtin_sizes[0]} ...")
    warm = Trainer(TrainConfig(scene="builtin", iterations=suite.schedule), scenes[0], rt)
    for _ in range(suite.warm_iterations):
        warm.step()
    state = warm.model.download()
    model = warm.params.download_model()
    del warm
    cases = []
    for scene in scenes:
        cam = scene.train[0]
        name = f"builtin {cam.width}x{cam.height}"
        say(f"{name}: {state.n:,} Gaussians")
        for c in scene.train:              # ray cast outside the timing
            scene.image(c)
        case = {"name": name, "gaussians": state.n, "width": cam.width, "height": cam.height,
                "forward": time_forward(rt, model, scene.train[:suite.forward_views], scene.background, suite),
                "train": {t: time_training(rt, training_config(t, "builtin", suite.schedule), scene, state,
                                           suite.warm_iterations, suite, suite.iterations) for t in TRAINING},
                "frames": (model, scene.train[:suite.forward_views], scene.background, suite.iterations)}
        cases.append(case)
    return cases


def frame_case(rt: Runtime, suite: Suite, name: str, model: GaussianModel, cams: list[Camera], iterations: int) -> dict:
    """A frame of these Gaussians over these cameras, no scene behind it: forward, and training iterations at
    GARDEN_AT whose targets are the frames' own renders with their colour channels reversed (any image serves:
    the cost does not depend on it)."""
    background = np.zeros(3, np.float32)
    forward = time_forward(rt, model, cams, background, suite)
    renderer, g = Renderer(rt), DeviceGaussians(rt, model)
    targets = {c.name: np.ascontiguousarray(renderer.render(g, c, model.sh_degree, background).image(rt)[..., ::-1])
               for c in cams}
    one = np.zeros((1, 3))                 # the trainer starts from one point, replaced at once by the model
    scene = Scene(root=Path(name), train=cams, test=[], points=one, colors=one + 0.5, background=background,
                  read_image=lambda c: targets[c.name])
    params = model.groups()
    state = GaussianSet(params, {k: np.zeros_like(v) for k, v in params.items()},
                        {k: np.zeros_like(v) for k, v in params.items()})
    cam = cams[0]
    return {"name": name, "gaussians": len(model), "width": cam.width, "height": cam.height, "forward": forward,
            "train": {t: time_training(rt, training_config(t, name, 30_000), scene, state, GARDEN_AT, suite, iterations)
                      for t in TRAINING},
            "frames": (model, cams, background, iterations)}


def synthetic_case(rt: Runtime, suite: Suite, say) -> dict:
    """A million random Gaussians in front of one camera."""
    n, (w, h) = suite.synthetic_gaussians, suite.synthetic_size
    name = f"random {n:,} {w}x{h}"
    say(f"{name} ...")
    rng = np.random.default_rng(suite.seed)
    model = random_model(rng, n, sh_degree=3, spread=2.0, scale_range=(0.003, 0.03))
    cam = Camera.look_at("random", (0.0, -5.0, 1.5), (0.0, 0.0, 0.0), w, h, fov_x=1.0)
    return frame_case(rt, suite, name, model, [cam], suite.synthetic_iterations)


def garden_case(rt: Runtime, suite: Suite, path: Path, say) -> dict:
    """gsplat's garden asset as gsplat's tests make its Gaussians (testing.gsplat_test_garden), with random SH
    coefficients up to degree 3, over its 3 cameras."""
    rng = np.random.default_rng(suite.seed)
    try:
        g, cams = gsplat_test_garden(path, rng)
    except (OSError, KeyError, ValueError) as e:
        raise InputError(path, f"is not gsplat's test_garden.npz ({e})") from None
    sh = np.concatenate([g.sh, rng.normal(0, 0.15, (len(g), 15, 3))], axis=1)
    model = GaussianModel(means=g.means, log_scales=g.log_scales, quats=g.quats, opacity_logits=g.opacity_logits,
                          sh=sh)
    name = f"garden {cams[0].width}x{cams[0].height}"
    say(f"{name}: {len(model):,} Gaussians ...")
    return frame_case(rt, suite, name, model, cams, suite.iterations)


def gsplat_side(rt: Runtime, case: dict, suite: Suite) -> dict:
    """The case's frames through gsplat (apps/gsplat_frames.py), with its first view's image against ours."""
    from .gsplat_frames import time_gsplat
    model, cams, background, iterations = case["frames"]
    ours = Renderer(rt).render(DeviceGaussians(rt, model), cams[0], model.sh_degree, background).image(rt)
    return time_gsplat(model, cams, background, ours, suite.rounds, iterations, GSPLAT_ABSGRAD)


def rel_l2(got, want) -> float:
    want = np.asarray(want, np.float64)
    err = np.linalg.norm(np.asarray(got, np.float64) - want) / max(float(np.linalg.norm(want)), 1e-30)
    return err if np.isfinite(got).all() else float("nan")


def accuracy(rt: Runtime, suite: Suite) -> list[dict]:
    """Each stage against the float64 references on one small random frame: relative L2 errors (NaN if the
    device gave a non-finite value). The backward is the whole chain, dL/dimage to every parameter, with the
    few pixels whose blend float32 may decide otherwise left out (they compare a different function)."""
    n, w, h = suite.accuracy_case
    rng = np.random.default_rng(suite.seed)
    model = random_model(rng, n, spread=1.0)
    cam = random_camera(rng, w, h)
    bg = rng.uniform(0, 1, 3)
    g = DeviceGaussians(rt, model)
    renderer = Renderer(rt, poison=True)
    res = renderer.render(g, cam, 3, bg)
    tiles_x = res.tiles_x
    params = dict(means=model.means, log_scales=model.log_scales, quats=model.quats,
                  opacity_logits=model.opacity_logits, sh=model.sh)
    p = project_reference(**params, cam=cam, sh_degree=3, tiles_x=tiles_x, tiles_y=res.tiles_y)
    radius = rt.to_host(res.proj.radius, n, np.int32)
    both = (radius > 0) & (p["radius"] > 0)
    co = rt.to_host(res.proj.conic_opacity, (n, 4))
    rows = [{"stage": "project", "quantity": q, "rel_l2": rel_l2(got[both], want[both])}
            for q, got, want in (("mean2d", rt.to_host(res.proj.mean2d, (n, 2)), p["mean2d"]),
                                 ("conic", co[:, :3], p["conic"]), ("opacity", co[:, 3], p["opacity"]),
                                 ("colour", rt.to_host(res.proj.rgb, (n, 3)), p["rgb"]),
                                 ("depth", rt.to_host(res.proj.depth, n), p["depth"]))]
    rows.append({"stage": "project", "quantity": "culling (share decided otherwise)",
                 "rel_l2": float(np.mean((radius > 0) != (p["radius"] > 0)))})
    _, gop, ranges = intersect_reference(p["mean2d"], p["radius"], p["alpha_extent"], p["tiles_touched"], p["depth"],
                                         tiles_x, res.tiles_y, alpha_cut=False)
    ref = rasterize_reference(p["mean2d"], p["conic"], p["opacity"], p["rgb"], gop, ranges, w, h, tiles_x, bg)
    image = res.image(rt)
    rows.append({"stage": "isect + sort + rasterize", "quantity": "image", "rel_l2": rel_l2(image, ref["image"])})

    target = rng.uniform(0, 1, image.shape).astype(np.float32)
    dL_dimage = rt.to_device(np.full(image.size, np.nan, np.float32))
    loss = Loss(renderer.context)
    loss(res.raster.image, rt.to_device(target), w, h, dL_dimage)
    got_loss = loss.read_stats()["loss"]
    x = image.astype(np.float64)
    rows.append({"stage": "loss", "quantity": "value",
                 "rel_l2": rel_l2([got_loss], [loss_reference.loss_value(x, target)])})
    rows.append({"stage": "loss", "quantity": "dL/dimage", "rel_l2": rel_l2(rt.to_host(dL_dimage, image.shape),
                                                                             loss_reference.loss_gradient(x, target))})

    undecided = undecided_pixels(p["mean2d"], p["conic"], p["opacity"], p["depth"], gop, ranges, w, h, tiles_x)
    grad_image = rng.normal(size=image.shape).astype(np.float32)
    grad_image[undecided] = 0.0
    sums = RasterizeBackward(renderer.context)(res, rt.to_device(grad_image), bg, GRADIENTS)
    widths = group_widths(g.sh_coeffs)
    grads = {k: rt.to_device(np.full(n * k_w, np.nan, np.float32)) for k, k_w in widths.items()}
    ProjectBackward(renderer.context).gradients(g, cam, 3, res, sums, GRADIENTS, grads)
    r = rasterize_backward_reference(p["mean2d"], p["conic"], p["opacity"], p["rgb"], gop, ranges, w, h, tiles_x, bg,
                                     grad_image)
    want = project_backward_reference(**params, cam=cam, sh_degree=3, v_mean2d=r["mean2d"], v_conic=r["conic"],
                                      v_opacity=r["opacity"], v_rgb=r["rgb"], visible=p["radius"] > 0)
    rows += [{"stage": "backward (rasterize + project)", "quantity": f"dL/d{k}",
              "rel_l2": rel_l2(rt.to_host(grads[k], (n, k_w)), want[k].reshape(n, -1))} for k, k_w in widths.items()]
    return rows


def _git_commit() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                             text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return (out.stdout.strip() or None) if out.returncode == 0 else None


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment(rt: Runtime) -> dict:
    d = rt.device
    return {"device": describe(d), "device_name": d.name.strip(), "platform": d.platform.name.strip(),
            "platform_version": d.platform.version.strip(), "device_version": d.version.strip(),
            "driver_version": d.driver_version.strip(), "capabilities": asdict(Capabilities.of(d)),
            "global_mem_bytes": int(d.global_mem_size), "host_cpu": _cpu_name(), "host_cores": os.cpu_count(),
            "dc4gs_cl": __version__, "commit": _git_commit(), "pyopencl": cl.VERSION_TEXT, "numpy": np.__version__,
            "python": platform.python_version(), "os": platform.platform()}


def run_suite(rt: Runtime, suite: Suite, say=lambda line: None, garden: Path | None = None,
              gsplat: bool = False) -> dict:
    """The suite's cases (with the garden asset's where given), each also through gsplat where asked."""
    report = {"suite_version": SUITE_VERSION, "suite": "quick" if suite == QUICK else "full",
              "settings": asdict(suite), "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "environment": environment(rt)}
    start = time.perf_counter()

    def done(case: dict) -> dict:   # its frames through gsplat where asked, then let go of them
        if gsplat:
            say(f"{case['name']} through gsplat ...")
            try:
                case["gsplat"] = gsplat_side(rt, case, suite)
            except Exception as e:   # another project's code on our frames: our measurements stay, without ratios
                case["gsplat_error"] = f"{type(e).__name__}: {e}"
                say(f"{case['name']}: gsplat failed ({case['gsplat_error']}); the case has no ratios")
        del case["frames"]
        return case

    cases = [done(case) for case in builtin_cases(rt, suite, say)] + [done(synthetic_case(rt, suite, say))]
    if garden is not None:
        cases.append(done(garden_case(rt, suite, garden, say)))
    report["cases"] = cases
    say("accuracy against the float64 references ...")
    report["accuracy"] = accuracy(rt, suite)
    report["seconds"] = round(time.perf_counter() - start, 1)
    return report


def gsplat_ratios(case: dict) -> dict[str, tuple[float, float]]:
    """Per run of the case that gsplat ran too: (gsplat's wall ms, ours / gsplat)."""
    side = case.get("gsplat")
    if side is None:
        return {}
    theirs = {"forward": side["forward"]["wall_ms"], **{f"train {t}": m["wall_ms"] for t, m in side["train"].items()}}
    return {run: (theirs[run], m["wall_ms"] / theirs[run]) for run, m in case_runs(case).items() if run in theirs}


# reports --------------------------------------------------------------------------------------------------
def case_runs(case: dict) -> dict[str, dict]:
    """A case's measured runs by name: "forward", then "train <configuration>" for each of TRAINING."""
    return {"forward": case["forward"], **{f"train {t}": v for t, v in case["train"].items()}}


def measurements(report: dict) -> dict[tuple[str, str, str], float]:
    """(case, run, quantity) -> value: every number two reports of one suite can be compared on."""
    out = {}
    for case in report["cases"]:
        for run, m in case_runs(case).items():
            for stage, ms in m["stages_ms"].items():
                out[(case["name"], run, f"{stage} ms")] = ms
            out[(case["name"], run, "device ms")] = m["device_ms"]
            out[(case["name"], run, "wall ms")] = m["wall_ms"]
            for quantity in COUNTS:
                out[(case["name"], run, COUNTS[quantity])] = m[quantity]
            if "bytes_per_gaussian" in m:
                out[(case["name"], run, "peak bytes / Gaussian")] = m["bytes_per_gaussian"]
        for run, (theirs, ratio) in gsplat_ratios(case).items():
            out[(case["name"], run, "gsplat wall ms")] = theirs
            out[(case["name"], run, "ours / gsplat")] = ratio
    for row in report["accuracy"]:
        out[("accuracy", row["stage"], row["quantity"])] = row["rel_l2"]
    return out


def markdown(report: dict) -> str:
    env = report["environment"]
    lines = [f"# dc4gs-cl bench (suite {report['suite_version']}, {report['suite']})", "",
             f"- device: {env['device']}; OpenCL {env['device_version']}, driver {env['driver_version']} "
             f"({env['platform_version']})",
             f"- host: {env['host_cpu']}, {env['host_cores']} cores; {env['os']}",
             f"- dc4gs-cl {env['dc4gs_cl']}" + (f" @ {env['commit']}" if env["commit"] else "")
             + f", pyopencl {env['pyopencl']}, numpy {env['numpy']}, Python {env['python']}",
             f"- {report['created']}, {report['seconds']} s; medians of {report['settings']['rounds']} rounds "
             "(device ms from OpenCL profiling events)", ""]
    for case in report["cases"]:
        runs = case_runs(case)
        stages = list(dict.fromkeys(s for m in runs.values() for s in m["stages_ms"]))
        lines += [f"## {case['name']}: {case['gaussians']:,} Gaussians, {case['forward']['pairs']:,} pairs", "",
                  "| stage (ms) | " + " | ".join(runs) + " |", "|---|" + "---:|" * len(runs)]
        for s in stages:
            lines.append(f"| {s} | " + " | ".join(f"{m['stages_ms'][s]:.2f}" if s in m["stages_ms"] else ""
                                                   for m in runs.values()) + " |")
        lines.append("| **device total** | " + " | ".join(f"**{m['device_ms']:.2f}**" for m in runs.values()) + " |")
        lines.append("| wall | " + " | ".join(f"{m['wall_ms']:.2f}" for m in runs.values()) + " |")
        for quantity, label in COUNTS.items():
            lines.append(f"| {label} | " + " | ".join(f"{m[quantity]:.{2 if quantity == 'host_ms' else 1}f}"
                                                      for m in runs.values()) + " |")
        lines.append("| peak bytes / Gaussian | " + " | ".join(f"{m['bytes_per_gaussian']:,.0f}"
                                                             if "bytes_per_gaussian" in m else ""
                                                             for m in runs.values())
                     + " |")
        if ratios := gsplat_ratios(case):
            side = case["gsplat"]
            lines.append("| gsplat wall | " + " | ".join(f"{ratios[r][0]:.2f}" if r in ratios else ""
                                                         for r in runs) + " |")
            lines.append("| **ours / gsplat** | " + " | ".join(f"**{ratios[r][1]:.2f}**" if r in ratios else ""
                                                           for r in runs) + " |")
            lines += ["", f"gsplat: the same Gaussians and cameras (its first view against ours: "
                          f"{side['image_psnr_db']:.1f} dB PSNR); beside AbsGS + DC4GS, its AbsGS (absgrad)."]
        if "gsplat_error" in case:
            lines += ["", f"gsplat failed on these frames: {case['gsplat_error']}"]
        lines.append("")
    n, w, h = report["settings"]["accuracy_case"]
    lines += [f"## Accuracy against the float64 references ({n:,} random Gaussians, {w}x{h})", "",
              "| stage | quantity | relative L2 error |", "|---|---|---:|"]
    lines += [f"| {r['stage']} | {r['quantity']} | {r['rel_l2']:.2e} |" for r in report["accuracy"]]
    return "\n".join(lines) + "\n"


def compare(a: dict, b: dict) -> list[str]:
    """B against A, line by line: each measurement of both and B / A (times: above 1 is slower)."""
    if (a["suite_version"], a["suite"]) != (b["suite_version"], b["suite"]):
        raise InputError(None, f"the reports ran different suites ({a['suite_version']} {a['suite']} and "
                               f"{b['suite_version']} {b['suite']}): their numbers do not compare line by line")
    ma, mb = measurements(a), measurements(b)
    lines = [f"A: {a['environment']['device']} ({a['environment']['driver_version']})",
             f"B: {b['environment']['device']} ({b['environment']['driver_version']})", "",
             "| case | run | quantity | A | B | B / A |", "|---|---|---|---:|---:|---:|"]
    for key in ma:
        if key in mb:
            va, vb = ma[key], mb[key]
            ratio = f"{vb / va:.2f}" if va else ""
            lines.append(f"| {' | '.join(key)} | {va:.3g} | {vb:.3g} | {ratio} |")
    return lines


REPORT_KEYS = {"suite_version", "suite", "environment", "cases", "accuracy"}   # what compare reads


def read_report(path: Path) -> dict:
    try:
        report = json.loads(path.read_text())
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror})") from e
    except ValueError:
        report = None
    if not isinstance(report, dict) or not REPORT_KEYS <= report.keys():
        raise InputError(path, "is not a report written by `dc4gs-cl bench`")
    return report


def report_stem(env: dict) -> str:
    return "bench-" + re.sub(r"[^a-z0-9]+", "-", f"{env['platform']} {env['device_name']}".lower()).strip("-")


# command line ---------------------------------------------------------------------------------------------
def cmd_bench(args) -> int:
    """`dc4gs-cl bench` (its arguments: cli.py)."""
    if args.compare:
        print("\n".join(compare(*(read_report(p) for p in args.compare))))
        return 0
    if args.garden is not None and not args.garden.is_file():
        raise InputError(args.garden, "does not exist (--garden takes gsplat's test_garden.npz)")
    if args.gsplat:
        from .gsplat_frames import available
        if (why := available()) is not None:
            raise InputError(None, f"--gsplat needs torch and gsplat with a CUDA device: {why}")
    rt = Runtime(args.device, profiling=True)
    say = lambda line: print(line, file=sys.stderr, flush=True)
    say(f"device: {describe(rt.device)}")
    report = run_suite(rt, QUICK if args.quick else FULL, say, args.garden, args.gsplat)
    text = markdown(report)
    stem = args.out / report_stem(report["environment"])
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(args.out, f"cannot be made ({e.strerror})") from e
    write_json(stem.with_suffix(".json"), report)
    write_atomic(stem.with_suffix(".md"), lambda tmp: tmp.write_text(text))
    print(text)
    say(f"written: {stem}.json, {stem}.md")
    return 0
