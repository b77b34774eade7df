"""`dc4gs-cl eval`: a trained run's test views rendered and measured (evaluate.py), the metrics merged into its
results (RunFolder.write_results)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError
from .model_source import ModelSource


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The `eval` command's arguments (cli.py adds --lpips and --device)."""
    p.add_argument("--model", type=Path, required=True, help="a training output folder")
    p.add_argument("--iteration", type=int, default=None, help="which saved iteration (default: the last)")
    p.add_argument("--no-renders", action="store_true", help="metrics only, no PNGs under test/")
    p.add_argument("--corrected-metrics", action="store_true",
                   help="also score each test view's right half after a colour correction fitted on its left half "
                        "(the Inria code's protocol for runs with --exposure), labelled corrected; the raw metrics "
                        "are as without it")


def cmd_eval(args) -> int:
    from ..evaluation.evaluate import evaluate, per_view_lines, summary
    from ..evaluation.metrics import lpips_metric
    from ..render import DeviceGaussians, Renderer, RenderOptions
    from ..runtime import Runtime

    source = ModelSource.of_run(args.model, args.iteration)
    run, iteration, model = source.run, source.iteration, source.model
    scene = run.load_scene(source.cfg)
    if not scene.test:
        raise InputError(run.config_path, "the run has no test views (test_every = 0)")
    lpips, lpips_note = lpips_metric(args.lpips)
    rt = Runtime(args.device)
    result = evaluate(rt, Renderer(rt, options=RenderOptions.of_model(None, source.antialiased)),
                      DeviceGaussians(rt, model), scene, scene.test, model.sh_degree,
                      None if args.no_renders else run.views_dir("test", iteration), lpips, lpips_note,
                      args.corrected_metrics or source.cfg.corrected_metrics)
    for line in run.write_results(iteration, result):
        print(line, file=sys.stderr)
    print(f"iteration {iteration}: {summary(result)} over {result['views']} test views; written to "
          f"{run.results_path}")
    print("\n".join(per_view_lines(result)))
    return 0
