"""`dc4gs-cl report`: the metrics of several runs drawn to one HTML page (or a PNG), and its bad input."""
import base64
import json
import re

import numpy as np
import pytest

from dc4gs_cl.cli import main

pytest.importorskip("matplotlib", reason="the report extra (matplotlib) is not installed")

RUN = ["train", "--scene", "builtin", "-r", "4", "--iterations", "40", "--no-progress"]


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    base, dc4gs = tmp_path_factory.mktemp("base"), tmp_path_factory.mktemp("dc4gs")
    assert main([*RUN, "--out", str(base), "--force"]) == 0
    assert main([*RUN, "--dc4gs", "--out", str(dc4gs), "--force"]) == 0
    return base, dc4gs


def png_pixels(data: bytes) -> np.ndarray:
    import matplotlib.image
    import io
    return matplotlib.image.imread(io.BytesIO(data), format="png")


def test_report_overlays_runs_and_shows_test_views(two_runs, tmp_path):
    out = tmp_path / "r.html"
    assert main(["report", *map(str, two_runs), "--out", str(out)]) == 0
    page = out.read_text()
    assert "(3dgs)" in page and "(3dgs+DC4GS)" in page
    evaluated = [json.loads(line) for line in (two_runs[0] / "metrics.jsonl").read_text().splitlines()]
    assert ("<th>test LPIPS</th>" in page) == any("test_lpips" in row for row in evaluated)   # where computed
    images = re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]+)"', page)
    curves = [data for alt, data in images if alt == "curves"]
    assert len(curves) == 1
    pixels = png_pixels(base64.b64decode(curves[0]))
    assert pixels.std() > 0.05                                     # drawn, not blank
    views = [alt for alt, _ in images if alt != "curves"]
    assert views.count("ground truth") == 4 and len(views) == 4 * 3   # 4 builtin test views: truth + 2 runs


def test_report_png_of_one_run(two_runs, tmp_path):
    out = tmp_path / "curves.png"
    assert main(["report", str(two_runs[0]), "--out", str(out)]) == 0
    assert png_pixels(out.read_bytes()).shape[0] > 400


@pytest.mark.parametrize("problem", ["missing", "no-metrics", "suffix"])
def test_report_bad_input(two_runs, tmp_path, capsys, problem):
    target = {"missing": tmp_path / "nope", "no-metrics": tmp_path, "suffix": two_runs[0]}[problem]
    out = tmp_path / ("r.txt" if problem == "suffix" else "r.html")
    assert main(["report", str(target), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out if problem == "suffix" else target) in err[0]
    assert not out.exists()


@pytest.mark.parametrize("row", ['{"iteration": 20, "loss": "0.1"}', '{"iteration": 20, "loss": 0.1, "gaussians": [1]}',
                                 '{"iteration": 20, "test_psnr": true}', '{"iteration": 20, "stage_ms": {"loss": "x"}}',
                                 '{"iteration": 20, "stage_ms": [1, 2]}'])
def test_report_names_a_metrics_row_of_the_wrong_type(two_runs, tmp_path, capsys, row):
    """A metrics.jsonl row whose numbers are not numbers: one line naming the file and the row, not a traceback
    from the plotting (a line cut short by a crash is still passed over)."""
    import shutil
    run = tmp_path / "run"
    shutil.copytree(two_runs[0], run)
    metrics = run / "metrics.jsonl"
    lines = metrics.read_text().splitlines()
    metrics.write_text("\n".join([lines[0], row, *lines[1:], '{"iteration": 3'] ) + "\n")
    out = tmp_path / "r.html"
    assert main(["report", str(run), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(metrics) in err[0] and "line 2" in err[0], err
    assert not out.exists()
