"""tools/frontier.py, the DC4GS frontier study: each (method, threshold scale) is a real run with the threshold it
names, a rerun adds only the runs its results file lacks, and "vs base at equal Gaussians" interpolates the base's
curve in log Gaussians."""
import json
import math

import pytest

from helpers import load_tool

frontier = load_tool("frontier")


def point(gaussians, psnr):
    return {"gaussians_final": gaussians, "psnr": psnr}


def test_psnr_against_the_base_at_equal_gaussians():
    base = [point(4000, 22.0), point(1000, 20.0), point(16000, 23.0)]
    assert frontier.at_equal_gaussians(point(2000, 21.5), base) == pytest.approx(0.5)     # halfway in log G
    assert frontier.at_equal_gaussians(point(8000, 22.0), base) == pytest.approx(-0.5)
    assert frontier.at_equal_gaussians(point(4000, 22.0), base) == pytest.approx(0.0)
    assert frontier.at_equal_gaussians(point(999, 30.0), base) is None                    # outside the base's range
    assert frontier.at_equal_gaussians(point(20000, 30.0), base) is None
    assert frontier.at_equal_gaussians(point(2000, 21.0), base[:1]) is None
    assert frontier.at_equal_gaussians(point(4000, 22.5), base[:1]) == pytest.approx(0.5)   # MCMC at the base's count


def test_sweep_runs_each_point_once_and_reports_it(tmp_path):
    args = ["--scenes", "builtin", "--bases", "absgs", "--methods", "base", "dcc", "--iterations", "40", "-r", "4",
            "--out", str(tmp_path)]
    assert frontier.main([*args, "--scales", "1", "3"]) == 0
    first = json.loads((tmp_path / "frontier.json").read_text())["runs"]
    assert [(r["method"], r["scale"]) for r in first] == [("base", 1), ("dcc", 1), ("base", 3), ("dcc", 3)]
    for r in first:
        assert r["split_threshold"] == pytest.approx(4e-4 * r["scale"])
        saved = json.loads((tmp_path / "runs" / r["key"].replace("|", "-") / "config.json").read_text())
        assert (saved["split_threshold"] == pytest.approx(r["split_threshold"])
                and saved["dc4gs"]["dcc"] == (r["method"] == "dcc"))
        assert math.isfinite(r["psnr"]) and r["gaussians_final"] > 0 and r["wall_s"] > 0
        assert sorted(r["per_view_psnr"]) == ["view_000.png", "view_008.png", "view_016.png", "view_024.png"]
    by = {(r["method"], r["scale"]): r for r in first}
    assert by["base", 3]["gaussians_final"] < by["base", 1]["gaussians_final"]   # a higher threshold splits less
    assert frontier.main([*args, "--scales", "1", "3", "2"]) == 0                 # only the new scale runs
    runs = json.loads((tmp_path / "frontier.json").read_text())["runs"]
    assert runs[:4] == first and [(r["method"], r["scale"]) for r in runs[4:]] == [("base", 2), ("dcc", 2)]
    text = (tmp_path / "frontier.md").read_text()
    assert text.count("\n| dcc |") == 3 and "| builtin | 48x36 | absgs | 40 | llff | dcc |" in text
    assert (tmp_path / "builtin-absgs-40.png").stat().st_size > 10_000


def test_a_resumed_sweep_keeps_its_scenes_resolution(tmp_path, capsys):
    """Run keys do not name -r: resuming at another one would mix image sizes on one curve, and MCMC's caps would
    come from runs of another size."""
    args = ["--scenes", "builtin", "--bases", "absgs", "--methods", "base", "--iterations", "20",
            "--out", str(tmp_path)]
    assert frontier.main([*args, "--scales", "1", "-r", "4"]) == 0
    with pytest.raises(SystemExit):
        frontier.main([*args, "--scales", "1", "2", "-r", "2"])
    assert "holds builtin's runs at -r 4, not -r 2" in capsys.readouterr().err
    assert frontier.main([*args, "--scales", "1", "2"]) == 0            # no -r: the recorded one, not the default
    runs = json.loads((tmp_path / "frontier.json").read_text())["runs"]
    assert [(r["scale"], r["resolution"], r["size"]) for r in runs] == [(1, 4, "48x36"), (2, 4, "48x36")]


def test_side_by_side_sweeps_keep_each_others_runs(tmp_path):
    """Two sweeps into one folder each hold the report as it was when they started; each finished run is added to
    the file as it is now, so neither drops the other's (and a rerun of a key replaces it, once)."""
    path = tmp_path / "frontier.json"
    entry = lambda key, psnr: {"key": key, "scene": "builtin", "base": "absgs", "method": "base", "scale": 1.0,
                               "split_threshold": 4e-4, "iterations": 40, "test_split": "llff", "size": "48x36",
                               "psnr": psnr, "ssim": 0.5, "per_view_psnr": {"view_000.png": psnr},
                               "gaussians_final": 100, "gaussians_peak": 120, "wall_s": 1.0, "output": "-"}
    frontier.record(path, "device A", entry("a", 20.0))          # sweep 1's first run
    frontier.record(path, "device A", entry("b", 21.0))          # sweep 2, started before it
    report = frontier.record(path, "device A", entry("a", 22.0))
    runs = json.loads(path.read_text())["runs"]
    assert report["runs"] == runs and report["device"] == "device A"
    assert [(r["key"], r["psnr"]) for r in runs] == [("b", 21.0), ("a", 22.0)]
    assert "| base | 1 |" in (tmp_path / "frontier.md").read_text()


def test_mcmc_is_capped_at_the_bases_counts_and_seeds_are_averaged(tmp_path, capsys):
    """mcmc (and mcmc-dcs) beside a base: each of its runs capped at the final count of the base's run of the same
    scale and seed; with several seeds each point's runs are averaged (the summary) and every run is a row."""
    args = ["--scenes", "builtin", "--bases", "absgs", "--methods", "base", "mcmc", "mcmc-dcs", "--iterations", "60",
            "-r", "4", "--scales", "1", "--seeds", "0", "5", "--out", str(tmp_path)]
    assert frontier.main(args) == 0
    runs = json.loads((tmp_path / "frontier.json").read_text())["runs"]
    assert [(r["method"], r["seed"]) for r in runs] == [("base", 0), ("mcmc", 0), ("mcmc-dcs", 0), ("base", 5),
                                                         ("mcmc", 5), ("mcmc-dcs", 5)]
    assert runs[0]["key"].endswith("|llff") and runs[3]["key"].endswith("|llff|seed5")   # seed 0 keeps old keys
    for base, *capped in (runs[:3], runs[3:]):
        for mcmc in capped:
            saved = json.loads((tmp_path / "runs" / mcmc["key"].replace("|", "-") / "config.json").read_text())
            assert saved["strategy"] == "mcmc" and saved["max_gaussians"] == base["gaussians_final"] == mcmc["cap"]
            assert saved["seed"] == base["seed"] and mcmc["gaussians_final"] <= mcmc["cap"]
            assert saved["dc4gs"]["dcs"] == (mcmc["method"] == "mcmc-dcs") and not saved["dc4gs"]["dcc"]
    points = frontier.mean_points([r for r in runs if r["method"] == "base"])
    assert len(points) == 1 and points[0]["seeds"] == 2
    assert points[0]["psnr_min"] <= points[0]["psnr"] <= points[0]["psnr_max"]
    text = (tmp_path / "frontier.md").read_text()
    assert text.count("\n| mcmc |") == 2 and f"cap {runs[1]['cap']:,}" in text
    for methods in (["mcmc-dcs", "base"], ["mcmc"]):   # before the base it is capped by, or without it
        with pytest.raises(SystemExit):
            frontier.main([*args[:5], *methods, *args[8:]])
        assert "give --methods base before mcmc" in capsys.readouterr().err
