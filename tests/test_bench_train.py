"""tools/bench_train.py: a scene's runs interleaved in turns give the same results as run one after the other
(only the timing may differ), each run measured on its own."""
import json

from helpers import load_tool

bench_train = load_tool("bench_train")

SAME = ("psnr", "ssim", "gaussians_initial", "gaussians_final", "gaussians_peak", "per_view_psnr")


def runs(tmp_path, turn):
    report = tmp_path / f"turn{turn}.json"
    args = ["--scenes", "builtin", "--strategies", "absgs", "absgs+dc4gs", "--iterations", "60", "-r", "4",
            "--turn", str(turn), "--json", str(report), "--out", str(tmp_path / f"runs{turn}")]
    assert bench_train.main(args) == 0
    return json.loads(report.read_text())


def test_interleaved_runs_match_runs_one_after_the_other(tmp_path, capsys):
    apart, interleaved = runs(tmp_path, 0), runs(tmp_path, 7)
    assert apart["turn"] == 0 and interleaved["turn"] == 7
    assert [r["strategy"] for r in interleaved["runs"]] == ["absgs", "absgs+dc4gs"]
    for a, b in zip(apart["runs"], interleaved["runs"]):
        assert {k: a[k] for k in SAME} == {k: b[k] for k in SAME}, a["strategy"]
        assert b["wall_ms_per_it"] > 0 and b["device_ms_per_it"]["rasterize_backward"] > 0
        assert b["host_peak_rss_per_run"] is False
    # densification ran, and DC4GS' own stage only in its run: each run's profiling events are its own
    assert any(r["gaussians_final"] != r["gaussians_initial"] for r in interleaved["runs"])
    plain, dc4gs = interleaved["runs"]
    assert "split_geometry" not in plain["device_ms_per_it"] and dc4gs["device_ms_per_it"]["split_geometry"] > 0
    assert "| builtin | absgs+dc4gs |" in capsys.readouterr().out


def test_strategy_specs_name_dc4gs_settings():
    import pytest
    assert bench_train.variant("absgs+dc4gs:every=4:track=0.5:shrink") == {
        "strategy": "absgs", "dcc": True, "dcs": True, "cost_every": 4, "track": 0.5, "other_scale": 0.625}
    assert bench_train.variant("3dgs+dcs:window") == {"strategy": "3dgs", "dcs": True, "pooling": "window"}
    for spec in ("absgs+dc4gs:often=2", "absgs+dc4gs:every", "absgs+dc4", "bogus"):
        with pytest.raises(ValueError, match="unknown strategy"):
            bench_train.variant(spec)


def test_a_scene_of_ones_own_is_taken_by_its_path(tmp_path):
    """tools/bench_train.py and frontier.py took only the shared scenes' names: a user's scene folder (here a
    NeRF one) is taken by its path, its runs' folders named after it; what is no scene is refused naming it."""
    from test_scene import nerf_scene
    scene = nerf_scene(tmp_path / "mine", {"camera_angle_x": 0.9}, [{"file_path": f"r_{i}"} for i in range(3)])
    assert bench_train.scene_path(str(scene)) == scene and bench_train.scene_path("builtin") == "builtin"
    assert bench_train.unknown_scenes([str(scene), "builtin"]) is None
    assert "nor scene folders: nowhere" in bench_train.unknown_scenes(["nowhere", str(scene)])
    loaded, resolution = bench_train.load(str(scene), 1, tmp_path / "cache")
    assert resolution == 1 and loaded.root == scene and len(loaded.train) + len(loaded.test) == 3
