"""`dc4gs-cl bench`: the quick suite runs end to end and writes a report whose every number is real (finite,
positive times, small errors against the float64 references); --compare reads two reports line by line."""
import copy
import json
import math

import numpy as np
import pytest

from conftest import scene_path
from dc4gs_cl.apps import bench
from dc4gs_cl.cli import main


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    assert main(["bench", "--quick", "--out", str(out)]) == 0
    written = sorted(p.name for p in out.iterdir())
    assert len(written) == 2 and written[0].endswith(".json") and written[1].endswith(".md")
    return out / written[0], json.loads((out / written[0]).read_text()), (out / written[1]).read_text()


def test_quick_suite_measures_every_stage_and_writes_both_reports(quick_report):
    _, report, text = quick_report
    assert report["suite_version"] == bench.SUITE_VERSION and report["suite"] == "quick"
    env = report["environment"]
    assert env["device_name"] and env["driver_version"] and env["pyopencl"]
    names = [c["name"] for c in report["cases"]]
    assert names == ["builtin 48x36", "builtin 96x72", "random 20,000 160x90"]
    for case in report["cases"]:
        assert case["gaussians"] > 1000 and case["forward"]["pairs"] > 0
        assert set(case["forward"]["stages_ms"]) == {"project", "isect", "sort", "rasterize"}
        for name, run in case["train"].items():
            stages = run["stages_ms"]
            assert {"loss", "rasterize_backward", "sum_pairs", "project_backward"} <= set(stages), name
            assert ("split_geometry" in stages) == ("DC4GS" in name)
            assert all(math.isfinite(v) and v > 0 for v in stages.values()), (name, stages)
            assert run["device_ms"] >= max(stages.values())
            assert 100 < run["bytes_per_gaussian"] < 1e5
        for name, run in bench.case_runs(case).items():   # per frame or iteration
            assert run["launches"] >= len(run["stages_ms"]) and run["syncs"] >= 1, (name, run)
            # set only where they changed: ~2 an iteration's launch sets, of the ~9 each passes
            assert 0 <= run["arguments"] < 4 * run["launches"], (name, run)
            assert run["host_ms"] == pytest.approx(run["wall_ms"] - run["device_ms"])
    rows = {(r["stage"], r["quantity"]): r["rel_l2"] for r in report["accuracy"]}
    assert len(rows) == 14
    for key, err in rows.items():   # NaN fails too
        assert err < 1e-3, key
    # the markdown names the device and holds every case's table and the accuracy table
    assert env["device"] in text and env["driver_version"] in text
    for name in names:
        assert f"## {name}" in text
    assert text.count("| **device total** |") == 3 and "dL/dmeans" in text
    assert text.count("| kernel launches |") == text.count("| blocking host syncs |") == 3
    assert text.count("| kernel arguments set |") == 3


def test_compare_prints_ratios_line_by_line(quick_report, tmp_path, capsys):
    path, report, _ = quick_report
    slower = copy.deepcopy(report)
    slower["environment"]["device"] = "a slower device"
    for case in slower["cases"]:
        for run in [case["forward"], *case["train"].values()]:
            run["stages_ms"] = {s: 2 * v for s, v in run["stages_ms"].items()}
            run["device_ms"] *= 2
    other = tmp_path / "slower.json"
    other.write_text(json.dumps(slower))
    capsys.readouterr()
    assert main(["bench", "--compare", str(path), str(other)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "a slower device" in lines[1]
    rows = [line.split(" | ") for line in lines if line.startswith("| builtin 48x36 | forward | ")]
    ratios = {r[2]: r[-1].rstrip(" |") for r in rows}
    assert ratios["project ms"] == "2.00" and ratios["device ms"] == "2.00" and ratios["wall ms"] == "1.00"
    assert any(line.startswith("| accuracy | loss | value |") and line.endswith("| 1.00 |") for line in lines)


def test_compare_refuses_other_suites_and_files_that_are_not_reports(quick_report, tmp_path, capsys):
    path, report, _ = quick_report
    full = dict(report, suite="full")
    other = tmp_path / "full.json"
    other.write_text(json.dumps(full))
    capsys.readouterr()
    assert main(["bench", "--compare", str(path), str(other)]) == 2
    assert "different suites" in capsys.readouterr().err
    junk = tmp_path / "junk.json"
    junk.write_text('{"hello": 1}')
    assert main(["bench", "--compare", str(path), str(junk)]) == 2
    err = capsys.readouterr().err
    assert "junk.json" in err and "not a report" in err
    assert main(["bench", "--compare", str(path), str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in capsys.readouterr().err


def test_runtime_counts_launches_and_blocking_syncs(rt):
    """What bench reports per iteration: each kernel enqueued is a launch; a read back and a write (pyopencl's
    blocking copies, which wait for the queue) are syncs; a fill and a queued write are neither."""
    import pyopencl as cl
    kernel = cl.Kernel(cl.Program(rt.context, "__kernel void one(__global int *x) { x[get_global_id(0)] = 1; }")
                       .build(), "one")
    buf = rt.buffer(16)
    launches, syncs = rt.launches, rt.syncs
    rt.fill(buf, np.int32(0), 16)
    rt.launch("test", kernel, 4, None, buf)
    assert (rt.launches - launches, rt.syncs - syncs) == (1, 0)
    rt.write(buf, np.zeros(4, np.int32))
    rt.launch("test", kernel, 4, None, buf)
    assert (rt.to_host(buf, 4, np.int32) == 1).all()
    assert (rt.launches - launches, rt.syncs - syncs) == (2, 2)
    rt.write_async(buf, np.full(4, 7, np.int32))   # queued, no wait: not a sync
    assert rt.syncs - syncs == 2 and (rt.to_host(buf, 4, np.int32) == 7).all() and rt.syncs - syncs == 3
    later = rt.to_host_later(buf, 4, np.int32)     # queued, no wait until its result is asked for, once
    rt.write_async(buf, np.full(4, 9, np.int32))
    assert rt.syncs - syncs == 3 and (later.result() == 7).all() and (later.result() == 7).all()
    assert rt.syncs - syncs == 4


def test_garden_case_and_the_gsplat_side_refused_without_it(rt, tmp_path, capsys):
    """--garden adds gsplat's asset as a case (skipped here without the shared data); --gsplat without torch and
    gsplat (CUDA) is refused in one line before anything runs, as is a --garden file that is not there."""
    from dc4gs_cl.apps.gsplat_frames import available
    if available() is None:
        pytest.skip("torch and gsplat with CUDA are here: the refusal cannot be shown")
    assert main(["bench", "--quick", "--gsplat", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--gsplat needs torch and gsplat" in err
    assert main(["bench", "--quick", "--garden", str(tmp_path / "no.npz"), "--out", str(tmp_path)]) == 2
    assert "no.npz" in capsys.readouterr().err and not list(tmp_path.iterdir())


def test_a_gsplat_failure_keeps_our_measurements(rt, monkeypatch):
    """gsplat's side is another project's code on our frames: where it fails, the case keeps our numbers, says why
    it has no ratios, and the suite goes on."""
    def failing(*args):
        raise RuntimeError("CUDA error: out of memory")
    monkeypatch.setattr(bench, "gsplat_side", failing)
    said = []
    report = bench.run_suite(rt, bench.QUICK, said.append, gsplat=True)
    assert report["cases"] and all(c["gsplat_error"] == "RuntimeError: CUDA error: out of memory" and
                                   "gsplat" not in c and c["train"] for c in report["cases"])
    assert sum("gsplat failed" in line for line in said) == len(report["cases"])
    assert bench.markdown(report).count("gsplat failed on these frames: RuntimeError") == len(report["cases"])


def test_garden_case_times_gsplats_asset(rt):
    case = bench.garden_case(rt, bench.QUICK, scene_path("gsplat_test_garden") / "test_garden.npz", lambda line: None)
    assert case["name"] == "garden 648x420" and case["gaussians"] == 111_785 and case["forward"]["pairs"] > 100_000
    model, cams, _, _ = case["frames"]
    assert model.sh_degree == 3 and len(cams) == 3
    for run in bench.case_runs(case).values():
        assert run["device_ms"] > 0 and run["launches"] > 0


def test_gsplat_gets_our_cameras_in_its_conventions(rng):
    """gsplat projects a point to K (V p) / z (pixel centres at +0.5, as ours): our projection's 2D means."""
    from dc4gs_cl.apps.gsplat_frames import camera_matrices
    from dc4gs_cl.reference.project import project_reference
    from dc4gs_cl.reference.testing import random_camera, random_model
    cams = [random_camera(rng, 64, 48), random_camera(rng, 40, 30)]
    model = random_model(rng, 200)
    viewmats, ks = camera_matrices(cams)
    for cam, v, k in zip(cams, viewmats, ks):
        ours = project_reference(model.means, model.log_scales, model.quats, model.opacity_logits, model.sh, cam,
                                 model.sh_degree, 4, 3)
        seen = ours["radius"] > 0
        assert seen.sum() > 20
        p = (np.c_[model.means, np.ones(len(model))] @ v.T.astype(np.float64))[:, :3]
        uv = p @ k.T.astype(np.float64)
        np.testing.assert_allclose(uv[seen, :2] / uv[seen, 2:], ours["mean2d"][seen], rtol=1e-5, atol=1e-3)
