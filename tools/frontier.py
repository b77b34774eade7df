"""DC4GS frontier study: test PSNR against final Gaussians and against training time, one curve per method, each
curve the base's split threshold swept. One point per method cannot tell better allocation from less densification
(any higher threshold gives fewer Gaussians at lower PSNR); a curve can.

    python tools/frontier.py [--scenes builtin temple_sparse_ring ...] [--bases absgs 3dgs]
                             [--methods base dc4gs dcc dcs mcmc mcmc-dcs] [--scales 0.5 1 1.5 2 4] [--seeds 0 1 2]
                             [--iterations 3000] [--test-split llff|interpolated] [-r K] [--out DIR] [--device D]
                             [--report-only]

A method is the base alone or with DC4GS (dc4gs: DCC and DCS), DCC alone or DCS alone (and, asked for,
dcs-middle: DCS' deterministic split at the middle, no costs, which tells its placement from its split, and
dc4gs-middle: DCC with that split, DC4GS without split costs, and dc4gs-shrink: DC4GS whose children's other
two axes shrink as 3DGS' children do, --dcs-other-scale 0.625); a scale multiplies the
base's split threshold (--split-threshold; the clone threshold stays). mcmc is MCMC densification beside the base,
its cap (--max-gaussians) swept instead: at each scale, the final Gaussian count of the base's run of that scale and
seed, so that its curve spans the base's range; mcmc-dcs is MCMC with DCS' placement (--strategy mcmc --dcs).
Every (scene, base, method, scale, seed) is one training run measured as tools/bench_train.py measures it (test
PSNR and SSIM per view, final and peak Gaussians, wall and device time), its folder kept under DIR. Each result is
added to DIR/frontier.json when its run ends and a rerun skips the runs that file holds (at the -r they used), so a
sweep that is interrupted, or spread over sessions, goes on where it stopped. After each run DIR/frontier.md
(tables) and DIR/<scene>-<base>-<iterations>[-interpolated].png (the `report` extra's matplotlib; skipped with a
note without it) are rewritten. Runs go scale by scale, every method at a scale back to back, so slow phases of a
shared machine spread over all methods.

Reading it: a method helps where its curve lies above its base's, more PSNR at the same number of Gaussians. For
each point of a method, "vs base at equal Gaussians" is its PSNR minus the base's interpolated at its Gaussian count
(linear in log Gaussians between the base's runs that bracket it; none outside the base's range). With several
--seeds a point is the mean over them (PSNR and Gaussians), drawn with the PSNR's spread (min to max) as a bar:
single test views move by more than a dB between seeds.
"""
from __future__ import annotations

import argparse
import fcntl
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_train  # noqa: E402 (a module of tools/, found through the line above)

from dc4gs_cl.config import MCMC_DEFAULT_CAP  # noqa: E402
from dc4gs_cl.densify import STRATEGIES  # noqa: E402
from dc4gs_cl.errors import InputError  # noqa: E402
from dc4gs_cl.files import write_atomic, write_json  # noqa: E402
from dc4gs_cl.runtime import Runtime, describe  # noqa: E402
from dc4gs_cl.scene.builtin import BUILTIN_SCENE  # noqa: E402
from dc4gs_cl.scene.camera import TEST_SPLITS  # noqa: E402

# method -> bench_train strategy suffix (mcmc: the strategy itself, its cap swept); the last four are not run by
# default (see the docstring)
METHODS = {"base": "", "dc4gs": "+dc4gs", "dcc": "+dcc", "dcs": "+dcs", "dcs-middle": "+dcs:middle",
           "dc4gs-middle": "+dc4gs:middle", "dc4gs-shrink": "+dc4gs:shrink", "mcmc": None,
           "mcmc-dcs": None}
DEFAULT_METHODS = ("base", "dc4gs", "dcc", "dcs")
SCALES = (0.5, 1.0, 1.5, 2.0, 4.0)
COLOURS = {"base": "black", "dc4gs": "tab:red", "dcc": "tab:blue", "dcs": "tab:green", "dcs-middle": "tab:olive",
           "dc4gs-middle": "tab:purple", "dc4gs-shrink": "tab:orange", "mcmc": "tab:cyan",
           "mcmc-dcs": "tab:pink"}


def run_key(scene: str, base: str, method: str, scale: float, iterations: int, test_split: str, seed: int = 0) -> str:
    return f"{scene}|{base}|{method}|{scale:g}|{iterations}|{test_split}" + (f"|seed{seed}" if seed else "")


def strategy_of(base: str, method: str, cap: int | None = None) -> str:
    """bench_train's strategy spec of a method beside a base."""
    if method.startswith("mcmc"):
        return f"mcmc{'+dcs' if method == 'mcmc-dcs' else ''}:cap={cap}"
    return base + METHODS[method]


def at_equal_gaussians(point: dict, base_points: list[dict]) -> float | None:
    """point's PSNR minus the base curve's at point's Gaussian count (linear in log Gaussians); None outside the
    base's range (a curve of one point: MCMC capped at its count)."""
    pts = sorted(base_points, key=lambda r: r["gaussians_final"])
    g = [math.log(r["gaussians_final"]) for r in pts]
    x = math.log(point["gaussians_final"])
    if not pts or not g[0] <= x <= g[-1]:
        return None
    return point["psnr"] - float(np.interp(x, g, [r["psnr"] for r in pts]))


def versus(runs: list[dict], reference_points: list[dict]) -> list[float]:
    """A method's seed-mean points against a reference curve at equal Gaussians (at_equal_gaussians), those in its
    range."""
    return [d for p in mean_points(runs) if (d := at_equal_gaussians(p, reference_points)) is not None]


def curves(runs: list[dict]) -> dict[tuple, dict[str, list[dict]]]:
    """(scene, base, iterations, test_split) -> method -> its runs by scale, then seed."""
    out: dict[tuple, dict[str, list[dict]]] = {}
    for r in runs:
        key = (r["scene"], r["base"], r["iterations"], r["test_split"])
        out.setdefault(key, {}).setdefault(r["method"], []).append(r)
    for methods in out.values():
        for pts in methods.values():
            pts.sort(key=lambda r: (r["scale"], r.get("seed", 0)))
    return out


def mean_points(runs: list[dict]) -> list[dict]:
    """A method's runs averaged over their seeds, scale by scale: mean PSNR, Gaussians (geometric) and wall time,
    the PSNR's min and max, the seeds."""
    by_scale: dict[float, list[dict]] = {}
    for r in runs:
        by_scale.setdefault(r["scale"], []).append(r)
    return [{"scale": scale, "seeds": len(rs), "psnr": float(np.mean([r["psnr"] for r in rs])),
             "psnr_min": min(r["psnr"] for r in rs), "psnr_max": max(r["psnr"] for r in rs),
             "gaussians_final": float(np.exp(np.mean([math.log(r["gaussians_final"]) for r in rs]))),
             "wall_s": float(np.mean([r["wall_s"] for r in rs]))} for scale, rs in sorted(by_scale.items())]


def markdown(report: dict) -> str:
    lines = [f"# DC4GS frontiers ({report['device']})", "",
             "PSNR on the test views against final Gaussians, the base's split threshold scaled; \"vs base\" is the "
             "PSNR minus the base curve's at the same Gaussian count (log-linear between its runs; - outside them); "
             "with several seeds the summary compares their means.", ""]
    summary = ["## Summary: mean PSNR vs base (and vs base + DC4GS) at equal Gaussians", "",
               "| scene | size | base | iterations | test split | method | points in base's range | mean vs base | "
               "range | vs base + DC4GS (points in its range) |", "|---|---|---|---:|---|---|---:|---:|---|---:|"]
    tables = []
    for (scene, base, iterations, split), methods in curves(report["runs"]).items():
        base_pts = mean_points(methods.get("base", []))
        size = next(iter(methods.values()))[0]["size"]
        tables += [f"## {scene} ({size}), {base}, {iterations:,} iterations, {split} test views", "",
                   "| method | scale | seed | split threshold (mcmc: cap) | Gaussians | PSNR | SSIM | "
                   "vs base at equal G | wall s | per view PSNR (worst first) |",
                   "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
        for method in METHODS:
            for r in methods.get(method, []):
                d = at_equal_gaussians(r, base_pts) if method != "base" else None
                views = sorted(r["per_view_psnr"].items(), key=lambda kv: kv[1])
                limit = f"cap {r['cap']:,}" if method.startswith("mcmc") else f"{r['split_threshold']:.2e}"
                tables.append(
                    f"| {method} | {r['scale']:g} | {r.get('seed', 0)} | {limit} | {r['gaussians_final']:,} | "
                    f"{r['psnr']:.2f} | {r['ssim']:.4f} | {'-' if d is None else f'{d:+.2f}'} | "
                    f"{r['wall_s']:.0f} | {', '.join(f'{Path(n).stem} {p:.2f}' for n, p in views)} |")
            if method != "base" and methods.get(method):
                ds = versus(methods[method], base_pts)
                mean = f"{np.mean(ds):+.2f} dB" if ds else "-"
                spread = f"{min(ds):+.2f} to {max(ds):+.2f}" if ds else "-"
                dc = versus(methods[method], mean_points(methods.get("dc4gs", []))) if method != "dc4gs" else []
                summary.append(f"| {scene} | {size} | {base} | {iterations:,} | {split} | {method} | "
                               f"{len(ds)} of {len(mean_points(methods[method]))} | {mean} | {spread} | "
                               f"{f'{np.mean(dc):+.2f} dB ({len(dc)})' if dc else '-'} |")
        tables.append("")
    return "\n".join(lines + summary + [""] + tables)


def plot(report: dict, out: Path) -> list[Path]:
    """One PNG per (scene, base, iterations, test split); [] without matplotlib."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    written = []
    for (scene, base, iterations, split), methods in curves(report["runs"]).items():
        fig, (by_count, by_time) = plt.subplots(1, 2, figsize=(11, 4.2))
        for method, runs in methods.items():
            label = base if method == "base" else method if method.startswith("mcmc") else f"{base}+{method}"
            pts = mean_points(runs)
            spread = [[p["psnr"] - p["psnr_min"] for p in pts], [p["psnr_max"] - p["psnr"] for p in pts]]
            for ax, x in ((by_count, [p["gaussians_final"] for p in pts]), (by_time, [p["wall_s"] for p in pts])):
                ax.errorbar(x, [p["psnr"] for p in pts], yerr=spread, fmt="o-", capsize=2, color=COLOURS[method],
                            label=label if pts[0]["seeds"] == 1 else f"{label} (mean of {pts[0]['seeds']} seeds)")
                for xi, p in zip(x, pts):
                    ax.annotate(f"{p['scale']:g}x", (xi, p["psnr"]), textcoords="offset points", xytext=(3, 3),
                                fontsize=7, color=COLOURS[method])
        by_count.set_xscale("log")
        by_count.set_xlabel("final Gaussians")
        by_time.set_xlabel("training wall time, s")
        by_count.set_ylabel("test PSNR, dB")
        by_count.legend(fontsize=8)
        size = next(iter(methods.values()))[0]["size"]
        fig.suptitle(f"{scene} {size}, {base}, {iterations:,} iterations, {split} test views: "
                     f"split threshold x scale (labels; mcmc: capped at the base's count there)", fontsize=10)
        fig.tight_layout()
        path = out / f"{scene}-{base}-{iterations}{'' if split == 'llff' else '-' + split}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def write_reports(report: dict, out: Path) -> None:
    write_json(out / "frontier.json", report)
    text = markdown(report)
    write_atomic(out / "frontier.md", lambda tmp: tmp.write_text(text))
    if not plot(report, out):
        print("matplotlib not installed (pip install -e '.[report]'): no plots", file=sys.stderr)


def record(path: Path, device: str, entry: dict) -> dict:
    """Add one finished run to the report at `path` and rewrite its tables and plots. The file is read again
    under a lock, so sweeps running side by side into one folder (e.g. a scene each) keep each other's runs."""
    with open(path.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        report = json.loads(path.read_text()) if path.is_file() else {"device": device, "runs": []}
        report["runs"] = [r for r in report["runs"] if r["key"] != entry["key"]] + [entry]
        write_reports(report, path.parent)
    return report


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=None,
                    help=f"\"{BUILTIN_SCENE}\", scenes of ../shared/data by name (default: all of them) and / or "
                         "the paths of scene folders of your own (COLMAP or NeRF)")
    ap.add_argument("--bases", nargs="+", default=["absgs", "3dgs"], choices=sorted(STRATEGIES))
    ap.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), choices=list(METHODS))
    ap.add_argument("--scales", nargs="+", type=float, default=list(SCALES),
                    help="multiples of the base's split threshold (default: %(default)s)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="a run per seed at each point (default 0)")
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--test-split", choices=TEST_SPLITS, default="llff")
    ap.add_argument("-r", "--resolution", type=int, default=None,
                    help=f"downscale factor (default: per scene, at most {bench_train.MAX_WIDTH} px wide; a resumed "
                         "sweep keeps the one its recorded runs of the scene used)")
    ap.add_argument("--out", type=Path, default=Path("frontier"), help="results and run folders (default: %(default)s)")
    ap.add_argument("--device", default=None)
    ap.add_argument("--report-only", action="store_true", help="rewrite the tables and plots from DIR/frontier.json")
    args = ap.parse_args(argv)
    if any(not (s > 0 and math.isfinite(s)) for s in args.scales):
        ap.error("--scales must be positive")
    methods = args.methods
    capped = [methods.index(m) for m in methods if m.startswith("mcmc")]
    if capped and ("base" not in methods or min(capped) < methods.index("base")):
        ap.error("mcmc's caps are the base's Gaussian counts: give --methods base before mcmc and mcmc-dcs")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "frontier.json"
    report = json.loads(path.read_text()) if path.is_file() else {"device": None, "runs": []}
    if args.report_only:
        write_reports(report, args.out)
        return 0
    available = bench_train.colmap_scenes() if bench_train.DATA.is_dir() else []
    scenes = args.scenes or [BUILTIN_SCENE, *available]
    if problem := bench_train.unknown_scenes(scenes):
        ap.error(problem)

    resolution = {}     # per scene: its recorded runs' -r (one curve, one image size), else the given or default one
    for name in scenes:
        recorded = {r["resolution"] for r in report["runs"]
                    if r["scene"] == name and r["test_split"] == args.test_split}
        if args.resolution and recorded and recorded != {args.resolution}:
            ap.error(f"{path} holds {name}'s runs at -r {', '.join(map(str, sorted(recorded)))}, not -r "
                     f"{args.resolution}: give that -r or another --out")
        resolution[name] = args.resolution or (min(recorded) if recorded else None)

    rt = Runtime(args.device, profiling=True)
    report["device"] = report["device"] or describe(rt.device)
    if report["device"] != describe(rt.device):
        ap.error(f"{path} holds runs on {report['device']}, this is {describe(rt.device)}: use another --out")
    done = {r["key"] for r in report["runs"]}
    with tempfile.TemporaryDirectory(prefix="frontier-") as tmp:
        for name in scenes:
            for base in args.bases:
                todo = [(scale, method, seed) for scale in args.scales for seed in args.seeds for method in args.methods
                        if run_key(name, base, method, scale, args.iterations, args.test_split, seed) not in done]
                if not todo:
                    continue
                try:
                    scene, r = bench_train.load(name, resolution[name], args.out, args.test_split)
                except InputError as e:
                    print(f"{name}: skipped, the scene does not load: {e}", file=sys.stderr)
                    break
                cam = scene.train[0]
                # the warm-up builds kernels only: any cap the device holds
                strategies = [strategy_of(base, m, MCMC_DEFAULT_CAP) for m in args.methods]
                bench_train.warm_up(rt, scene, strategies, r, Path(tmp) / "warm-up")
                threshold = STRATEGIES[base].default_config().split_threshold
                for scale, method, seed in todo:
                    key = run_key(name, base, method, scale, args.iterations, args.test_split, seed)
                    if key in done:          # a sweep running beside this one has recorded it meanwhile
                        continue
                    cap = None
                    if method.startswith("mcmc"):   # the base's final count at this scale and seed (run or recorded)
                        base_key = run_key(name, base, "base", scale, args.iterations, args.test_split, seed)
                        cap = next(r["gaussians_final"] for r in report["runs"] if r["key"] == base_key)
                    settings = {} if method.startswith("mcmc") else {"split_threshold": threshold * scale}
                    cfg = bench_train.config(scene, strategy_of(base, method, cap), args.iterations, r, seed=seed,
                                             test_split=args.test_split, **settings)
                    folder = args.out / "runs" / key.replace("|", "-")
                    run = bench_train.train_one(rt, scene, cfg, folder)
                    entry = {
                        "key": key, "scene": name, "base": base, "method": method, "scale": scale, "seed": seed,
                        "split_threshold": None if cap else threshold * scale, "cap": cap,
                        "iterations": args.iterations,
                        "test_split": args.test_split, "resolution": r, "size": f"{cam.width}x{cam.height}",
                        "psnr": run["psnr"], "ssim": run["ssim"], "per_view_psnr": run["per_view_psnr"],
                        "gaussians_final": run["gaussians_final"], "gaussians_peak": run["gaussians_peak"],
                        "wall_s": run["wall_ms_per_it"] * args.iterations / 1e3,
                        "device_ms_per_it": sum(run["device_ms_per_it"].values()), "output": str(folder)}
                    report = record(path, report["device"], entry)
                    done = {r["key"] for r in report["runs"]}
                    print(f"{key}: {run['gaussians_final']:,} Gaussians, PSNR {run['psnr']:.2f} dB, "
                          f"{entry['wall_s']:.0f} s", flush=True)
    write_reports(report, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
