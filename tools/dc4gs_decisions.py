"""Why DC4GS decides as it does: at every densification step of a DC4GS run, the base's split decisions and
DCC's on the same window of statistics, the Gaussians DCC withholds, and where DCS cuts. On the built-in scene,
whose surfaces are known, also whether those Gaussians straddle true colour edges and whether DCS' cut lands on
the edge.

    python tools/dc4gs_decisions.py [--scene builtin|FOLDER] [--base absgs] [--iterations 3000] [-r K]
                                    [--test-split llff|interpolated] [--out DIR] [--device D]

Per densification step (tables in DIR/decisions.md, every number in DIR/decisions.json):
- candidates: large Gaussians (max scale > percent_dense x extent) whose base split criterion reaches the
  threshold (what the base would split); DCC splits those whose DC-weighted criterion reaches it too; withheld
  = candidates DCC does not split. DCC's criterion is the base's per-view term times (1 - kappa_v), kappa_v the
  view's directional consistency, so it never exceeds the base's: "1 - kappa" = DCC / base criterion, the
  factor by which DCC scales a Gaussian's criterion (its threshold, in effect, is the base's divided by it).
- known geometry (built-in scene): every candidate's principal axis, -3 to 3 sigma, sampled at 61 points and
  ray cast from the training cameras that see its centre (the scene's own ray caster, no rasterizer): the colour
  steps between samples (summed over RGB, averaged over the cameras); an edge is a step of at least EDGE_STEP.
  DCS' cut of a Gaussian split at x lies at (6x - 3) sigma; its distance from the nearest edge against the
  middle's (a cut at 0, where a split without DCS centres its children) and a cut drawn uniformly over DCS'
  search interval's (what a pick that knew nothing would give).
- DIR/withheld-<iteration>.jpg at the middle densification step: a test view rendered from the model, from the
  withheld Gaussians alone, from those DCC splits alone, and the model's error.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from dc4gs_cl.config import TrainConfig
from dc4gs_cl.densify import STRATEGIES, DC4GSConfig
from dc4gs_cl.densify.dc4gs import search_interval, split_positions
from dc4gs_cl.files import write_atomic, write_json
from dc4gs_cl.geometry import principal_axis
from dc4gs_cl.model import GaussianModel
from dc4gs_cl.render import DeviceGaussians
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene import builtin
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.camera import TEST_SPLITS
from dc4gs_cl.statistics import SPLIT_COSTS
from dc4gs_cl.train import Trainer

SAMPLES = 61          # points along a candidate's axis, -3 to 3 sigma
EDGE_STEP = 0.15      # a colour step (sum over RGB, 0.1 sigma apart) at least this large is an edge
PROFILE_VIEWS = 8     # training cameras ray cast per candidate (those that see its centre, spread over the ring)


def axis_profiles(means: np.ndarray, sigma: np.ndarray, direction: np.ndarray, cams) -> tuple[np.ndarray, np.ndarray]:
    """Colour steps along each Gaussian's axis, averaged over the cameras that see its centre: (M, SAMPLES - 1)
    steps, and (M,) how many cameras saw it."""
    t = np.linspace(-3, 3, SAMPLES)
    points = means[:, None, :] + t[None, :, None] * sigma[:, None, None] * direction[:, None, :]   # (M, S, 3)
    steps = np.zeros((len(means), SAMPLES - 1))
    seen = np.zeros(len(means))
    for cam in cams[:: max(1, len(cams) // PROFILE_VIEWS)]:
        cam_pts = means @ cam.R.T + cam.t
        u = cam.fx * cam_pts[:, 0] / np.maximum(cam_pts[:, 2], 1e-9) + cam.cx
        v = cam.fy * cam_pts[:, 1] / np.maximum(cam_pts[:, 2], 1e-9) + cam.cy
        sees = (cam_pts[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        if not sees.any():
            continue
        rays = points[sees].reshape(-1, 3) - cam.center
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        colour, _ = builtin.cast_rays(cam.center.astype(np.float32)[:, None], rays.T.astype(np.float32))
        colour = colour.T.reshape(-1, SAMPLES, 3)
        steps[sees] += np.abs(np.diff(colour, axis=1)).sum(axis=2)
        seen[sees] += 1
    return steps / np.maximum(seen, 1)[:, None], seen


def quartiles(x: np.ndarray) -> str:
    return "-" if len(x) == 0 else " / ".join(f"{q:.2f}" for q in np.percentile(x, [25, 50, 75]))


class Recorder:
    """The strategy's observer (Strategy.before_densify): records each step's decisions before it densifies."""

    def __init__(self, trainer: Trainer, known_geometry: bool):
        self.trainer, self.known_geometry, self.steps, self.snapshot = trainer, known_geometry, [], None
        self.uniform = np.random.default_rng(0)   # the baseline of cuts drawn uniformly over DCS' search interval
        trainer.strategy.before_densify = self.record
        c = trainer.strategy.config
        self.show_at = (c.densify_from + c.densify_until) // 2   # the panels: the first step from here on

    def record(self, gs, window, it) -> None:
        s = self.trainer.strategy
        c = s.config
        base_v, dcc_v = s.base_split_criterion(window), s.split_criterion(window)
        large = s.large(gs)
        candidates = large & (base_v >= c.split_threshold)
        split = large & (dcc_v >= c.split_threshold)
        withheld = candidates & ~split
        factor = np.where(base_v > 0, dcc_v / np.where(base_v > 0, base_v, 1), 0)[candidates]
        step = {"iteration": it, "gaussians": gs.n, "candidates": int(candidates.sum()), "split": int(split.sum()),
                "withheld": int(withheld.sum()), "split_not_candidates": int((split & ~candidates).sum()),
                "one_minus_kappa_quartiles": np.percentile(factor, [25, 50, 75]).tolist() if len(factor) else []}
        if self.known_geometry and candidates.any():
            idx = np.flatnonzero(candidates)
            _, sigma, direction = principal_axis(gs.params["log_scales"][idx], gs.params["quats"][idx])
            steps, seen = axis_profiles(gs.params["means"][idx].astype(np.float64), sigma, direction,
                                        self.trainer.scene.train)
            at = (np.arange(SAMPLES - 1) + 0.5) * 6 / (SAMPLES - 1) - 3     # where each step lies, in sigma
            peak = steps.max(axis=1)
            is_split = split[idx]
            x = split_positions(window[SPLIT_COSTS][idx], s.dc4gs.split_pick)
            cut = 6 * x - 3
            edge = (peak >= EDGE_STEP) & (seen > 0)
            on_edge = edge & is_split
            edges = np.where(steps >= EDGE_STEP, at, np.inf)             # (M, SAMPLES - 1): the edges' positions
            nearest = lambda cut_at: np.abs(cut_at[:, None] - edges).min(axis=1)
            step.update({
                "seen": int((seen > 0).sum()),
                "edge_fraction_split": float(edge[is_split].mean()) if is_split.any() else None,
                "edge_fraction_withheld": float(edge[~is_split].mean()) if (~is_split).any() else None,
                "colour_variation_split": float(np.median(steps[is_split].sum(axis=1))) if is_split.any() else None,
                "colour_variation_withheld": float(np.median(steps[~is_split].sum(axis=1)))
                                             if (~is_split).any() else None,
                "cut_to_edge": nearest(cut)[on_edge].tolist(),
                "middle_to_edge": nearest(np.zeros_like(cut))[on_edge].tolist(),
                "uniform_to_edge": nearest(6 * self.uniform.uniform(*search_interval(window[SPLIT_COSTS].shape[1]),
                                                                    len(cut)) - 3)[on_edge].tolist(),
                "cut_is_middle": float(np.mean(x[on_edge] == 0.5)) if on_edge.any() else None})
        self.steps.append(step)
        if self.snapshot is None and it >= self.show_at:
            self.snapshot = (it, self.trainer.sh_degree, {k: v.copy() for k, v in gs.params.items()}, withheld, split)


def render_panels(rt: Runtime, trainer: Trainer, sh_degree: int, params: dict, withheld: np.ndarray,
                  split: np.ndarray, path: Path) -> bool:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    scene = trainer.scene
    cam = (scene.test or scene.train)[0]
    target = scene.image(cam)

    def render(mask):
        model = GaussianModel.from_groups({k: v[mask] for k, v in params.items()})
        if len(model) == 0:
            return np.broadcast_to(scene.background, target.shape)
        return trainer.renderer.render(DeviceGaussians(rt, model), cam, sh_degree, scene.background).image(rt)

    everything = render(np.ones(len(withheld), bool))
    panels = [(everything, "model"), (render(withheld), f"withheld by DCC ({withheld.sum():,})"),
              (render(split), f"split by DCC ({split.sum():,})"),
              (np.clip(np.abs(everything - target).sum(axis=2) * 2, 0, 1), "model error x2 (sum over RGB)"),
              (target, "ground truth")]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 3.2 * target.shape[0] / target.shape[1] + 0.4))
    for ax, (image, title) in zip(axes, panels):
        ax.imshow(np.clip(image, 0, 1), cmap="magma" if image.ndim == 2 else None)
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110, pil_kwargs={"quality": 88})   # a JPEG: the panels are photographs
    plt.close(fig)
    return True


def markdown(report: dict) -> str:
    lines = [f"# DC4GS decisions: {report['scene']} ({report['size']}), {report['strategy']}, "
             f"{report['iterations']:,} iterations", "", f"Device: {report['device']}. Split threshold "
             f"{report['threshold']:g}; candidates = what the base would split, withheld = candidates DCC does not "
             "split; 1 - kappa = DCC criterion / base criterion over the candidates (25th / 50th / 75th percentile).",
             "", "| iteration | Gaussians | candidates | DCC splits | withheld | 1 - kappa |",
             "|---:|---:|---:|---:|---:|---|"]
    for s in report["steps"]:
        lines.append(f"| {s['iteration']:,} | {s['gaussians']:,} | {s['candidates']:,} | {s['split']:,} | "
                     f"{s['withheld']:,} | {' / '.join(f'{q:.2f}' for q in s['one_minus_kappa_quartiles']) or '-'} |")
    total = {k: sum(s[k] for s in report["steps"]) for k in ("candidates", "split", "withheld", "split_not_candidates")}
    lines += ["", f"Over the run: {total['candidates']:,} candidates, DCC split {total['split']:,} "
                  f"({total['split'] / max(total['candidates'], 1):.0%}), withheld {total['withheld']:,}; split by DCC "
                  f"but not a candidate: {total['split_not_candidates']:,}."]
    geo = [s for s in report["steps"] if "seen" in s]
    if geo:
        def pooled(key):
            return np.array([v for s in geo for v in s[key]])
        def mean_of(key):
            vals = [s[key] for s in geo if s[key] is not None]
            return f"{np.mean(vals):.2f}" if vals else "-"
        cut, middle, uniform = pooled("cut_to_edge"), pooled("middle_to_edge"), pooled("uniform_to_edge")
        lines += ["", "## Known geometry (the scene's ray caster along each candidate's axis, -3 to 3 sigma)", "",
                  "| | split by DCC | withheld by DCC |", "|---|---:|---:|",
                  f"| has an edge (a colour step >= {EDGE_STEP}), mean over steps | {mean_of('edge_fraction_split')} | "
                  f"{mean_of('edge_fraction_withheld')} |",
                  f"| colour variation along the axis (sum of steps), median, mean over steps | "
                  f"{mean_of('colour_variation_split')} | {mean_of('colour_variation_withheld')} |", "",
                  f"DCS' cut against the edges: {len(cut):,} split Gaussians with an edge on their axis; distance from "
                  "the nearest edge, in sigma:", "",
                  "| cut | quartiles | within 0.25 sigma | within 0.5 sigma | nearer than DCS' cut |",
                  "|---|---|---:|---:|---:|"]
        for label, dist in (("DCS (its x_opt)", cut), ("the middle (x = 0.5)", middle),
                            ("uniform over DCS' search interval", uniform)):
            nearer = "-" if dist is cut else f"{np.mean(dist < cut):.0%}"
            lines.append(f"| {label} | {quartiles(dist)} | {np.mean(dist <= 0.25):.0%} | {np.mean(dist <= 0.5):.0%} | "
                         f"{nearer} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=builtin.BUILTIN_SCENE)
    ap.add_argument("--base", default="absgs", choices=sorted(STRATEGIES))
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("-r", "--resolution", type=int, default=None)
    ap.add_argument("--test-split", choices=TEST_SPLITS, default="llff",
                    help="the held-out views (the panels show the first)")
    ap.add_argument("--out", type=Path, default=Path("decisions"))
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    scene = load_scene(args.scene, resolution=args.resolution, cache_dir=args.out / "undistorted",
                       test_split=args.test_split)
    scene.read_all_images()
    rt = Runtime(args.device)
    cfg = TrainConfig(scene=args.scene, iterations=args.iterations, resolution=args.resolution, strategy=args.base,
                      test_split=args.test_split, dc4gs=DC4GSConfig(dcc=True, dcs=True))
    trainer = Trainer(cfg, scene, rt)   # steps alone: no checkpoint nor model to write
    recorder = Recorder(trainer, known_geometry=args.scene == builtin.BUILTIN_SCENE)
    while trainer.iteration < cfg.iterations:
        trainer.step()
    cam = scene.train[0]
    report = {"device": describe(rt.device), "scene": args.scene, "size": f"{cam.width}x{cam.height}",
              "strategy": trainer.strategy.label, "iterations": args.iterations,
              "threshold": trainer.strategy.config.split_threshold, "steps": recorder.steps}
    if recorder.snapshot is not None:
        at, *snapshot = recorder.snapshot
        if render_panels(rt, trainer, *snapshot, args.out / f"withheld-{at}.jpg"):
            report["panels"] = f"withheld-{at}.jpg"
    write_json(args.out / "decisions.json", report)
    text = markdown(report)
    write_atomic(args.out / "decisions.md", lambda tmp: tmp.write_text(text))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
