"""`dc4gs-cl report DIR [DIR ...]`: a training report drawn from run folders' metrics.jsonl (train/log.py).

Curves over iterations (loss, training-view PSNR, test PSNR at the evaluation points, Gaussian count,
iterations per second), several runs overlaid (base against DC4GS, as the paper's teaser sets them),
test PSNR against Gaussians, and the last evaluation's test views beside their ground truth. Written as
one self-contained HTML page (images inlined) or, for an --out ending in .png, the curves alone.
matplotlib is an optional extra: pip install "dc4gs-cl[report]".
"""
from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ..files import write_atomic
from ..run_folder import GROUND_TRUTH, RENDERS, RunFolder

REPORT_VIEWS = 4   # test views shown beside their ground truth
CURVES = (          # (metrics key, axis label, log scale)
    ("loss", "training loss", True),
    ("train_psnr", "PSNR of the training view (dB)", False),
    ("test_psnr", "test PSNR (dB)", False),
    ("gaussians", "Gaussians", False),
    ("it_per_s", "iterations per second", False),
)


@dataclass
class RunMetrics:
    label: str
    run: RunFolder
    samples: list[dict]       # rows with "loss"
    evaluations: list[dict]   # rows with "test_psnr"

    @staticmethod
    def read(path: Path) -> "RunMetrics":
        run = RunFolder(path)
        if not run.path.is_dir():
            raise InputError(path, "no such run folder")
        rows = run.read_metrics()
        if not rows:
            raise InputError(run.metrics_path, "no metrics to report (a run made before metrics.jsonl, or one "
                                               "that has not reached its 10th iteration)")
        label = run.path.resolve().name
        if run.config_path.is_file():
            cfg = run.read_config()
            from ..train.schedule import Schedule
            label += f" ({Schedule(cfg).strategy().label})"
        return RunMetrics(label, run, [r for r in rows if "loss" in r], [r for r in rows if "test_psnr" in r])

    def series(self, key: str) -> tuple[list[int], list[float]]:
        rows = self.evaluations if key.startswith("test_") else self.samples
        pairs = [(r["iteration"], r[key]) for r in rows if key in r]
        return [p[0] for p in pairs], [p[1] for p in pairs]


def _pyplot():
    try:
        import matplotlib
    except ImportError:
        raise InputError(None, 'report needs matplotlib: pip install "dc4gs-cl[report]"') from None
    matplotlib.use("Agg")   # files only, no display
    import matplotlib.pyplot as plt
    return plt


def curves_png(runs: list[RunMetrics]) -> bytes:
    plt = _pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5), constrained_layout=True)
    for ax, (key, title, log) in zip(axes.flat, CURVES):
        for run in runs:
            x, y = run.series(key)
            ax.plot(x, y, "o-" if key.startswith("test_") else "-", label=run.label, linewidth=1.2, markersize=4)
        ax.set_title(title)
        ax.set_xlabel("iteration")
        if log:
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    ax = axes.flat[len(CURVES)]   # the paper's comparison: quality against model size
    for run in runs:
        gaussians = dict(zip(*run.series("gaussians")))
        points = [(gaussians.get(r["iteration"]), r["test_psnr"]) for r in run.evaluations]
        points = [p for p in points if p[0] is not None]
        ax.plot([p[0] for p in points], [p[1] for p in points], "o-", label=run.label)
    ax.set_title("test PSNR (dB) against Gaussians")
    ax.set_xlabel("Gaussians")
    ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def _img(data: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(data).decode()}">'


def views_html(runs: list[RunMetrics]) -> str:
    """The last evaluated iteration's first REPORT_VIEWS test views: ground truth, then each run's render."""
    # each run's last rendered test views
    last = [iterations[-1] if (iterations := run.run.rendered_iterations("test")) else None for run in runs]
    rendered = [run.run.views_dir("test", it) if it is not None else None for run, it in zip(runs, last)]
    first = next((f for f in rendered if f is not None), None)
    if first is None:
        return "<p>No test views were rendered (no test/ours_N/ folder).</p>"
    names = sorted(p.name for p in (first / GROUND_TRUTH).glob("*.png"))[:REPORT_VIEWS]
    head = "<tr><th>view</th><th>ground truth</th>" + "".join(
        f"<th>{html.escape(r.label)}<br>{html.escape(f.name) if f else ''}</th>"
        for r, f in zip(runs, rendered)) + "</tr>"
    rows = []
    for name in names:
        cells = [f"<td>{html.escape(name)}</td>",
                 f"<td>{_img((first / GROUND_TRUTH / name).read_bytes(), 'ground truth')}</td>"]
        for run, folder, iteration in zip(runs, rendered, last):
            path = folder / RENDERS / name if folder else None
            if path is None or not path.is_file():
                cells.append("<td>-</td>")
                continue
            psnr = _view_psnr(run.run, iteration, name)
            cells.append(f"<td>{_img(path.read_bytes(), run.label)}<br>{psnr}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table>{head}{''.join(rows)}</table>"


def _view_psnr(run: RunFolder, iteration: int, name: str) -> str:
    try:
        return f"{run.read_results(iteration, per_view=True)['PSNR'][name]:.2f} dB"
    except (OSError, ValueError, KeyError, TypeError):
        return ""


def summary_html(runs: list[RunMetrics]) -> str:
    lpips = any("test_lpips" in ev for r in runs for ev in r.evaluations)   # VGG's, where a run computed it
    corrected = any("test_psnr_corrected" in ev for r in runs for ev in r.evaluations)   # --corrected-metrics
    head = ("<tr><th>run</th><th>iterations</th><th>Gaussians</th><th>test PSNR</th><th>test SSIM</th>" +
            ("<th>test LPIPS</th>" if lpips else "") +
            ("<th>test PSNR, corrected</th>" if corrected else "") + "<th>training time</th></tr>")
    rows = []
    for r in runs:
        last, ev = r.samples[-1] if r.samples else {}, r.evaluations[-1] if r.evaluations else {}
        rows.append(f"<tr><td>{html.escape(r.label)}</td><td>{last.get('iteration', '-'):,}</td>"
                    f"<td>{last.get('gaussians', 0):,}</td><td>{ev.get('test_psnr', float('nan')):.2f} dB</td>"
                    f"<td>{ev.get('test_ssim', float('nan')):.4f}</td>" +
                    (f"<td>{ev.get('test_lpips', float('nan')):.4f}</td>" if lpips else "") +
                    (f"<td>{ev.get('test_psnr_corrected', float('nan')):.2f} dB</td>" if corrected else "") +
                    f"<td>{last.get('elapsed_s', float('nan')):.0f} s</td></tr>")
    return f"<table>{head}{''.join(rows)}</table>"


PAGE = """<!doctype html><html><head><meta charset="utf-8"><title>dc4gs-cl report</title><style>
body {{ font-family: sans-serif; margin: 1.5em; }} table {{ border-collapse: collapse; }}
td, th {{ border: 1px solid #ccc; padding: 4px 8px; text-align: center; vertical-align: top; }}
img {{ max-width: 360px; }} .curves img {{ max-width: 100%; }}
</style></head><body><h1>dc4gs-cl training report</h1>{summary}<h2>Curves</h2><div class="curves">{curves}</div>
<h2>Test views</h2>{views}</body></html>
"""


def write_report(dirs: list[Path], out: Path) -> None:
    runs = [RunMetrics.read(Path(d)) for d in dirs]
    curves = curves_png(runs)
    if out.suffix.lower() == ".png":
        write_atomic(out, lambda tmp: tmp.write_bytes(curves))
        return
    page = PAGE.format(summary=summary_html(runs), curves=_img(curves, "curves"), views=views_html(runs))
    write_atomic(out, lambda tmp: tmp.write_text(page, encoding="utf-8"))


def add_arguments(p) -> None:
    p.add_argument("runs", type=Path, nargs="+", metavar="DIR", help="training output folders (their metrics.jsonl)")
    p.add_argument("--out", type=Path, default=None,
                   help="report.html (one page: curves, summary, test views) or a .png (the curves alone); "
                        "default: DIR/report.html for one run, report.html here for several")


def cmd_report(args) -> int:
    out = args.out or (args.runs[0] / "report.html" if len(args.runs) == 1 else Path("report.html"))
    if out.suffix.lower() not in (".html", ".htm", ".png"):
        raise InputError(out, "--out must end in .html or .png")
    write_report(args.runs, out)
    print(f"wrote {out}")
    return 0
