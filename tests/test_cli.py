"""The command line: help, devices, render, and bad input (exit code 2, the file named, no output)."""
import shutil
import subprocess
import sys

import numpy as np
import pytest

from dc4gs_cl.cli import main
from dc4gs_cl.ply import write_ply
from dc4gs_cl.scene.images import read_image
from dc4gs_cl.testing import random_model


def run_cli(*args) -> subprocess.CompletedProcess:
    exe = shutil.which("dc4gs-cl") or sys.executable
    cmd = [exe, *args] if exe.endswith("dc4gs-cl") else [exe, "-m", "dc4gs_cl", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def test_help_lists_the_commands():
    out = run_cli("--help")
    assert out.returncode == 0
    for command in ("devices", "render", "train", "eval", "view", "export", "report"):
        assert command in out.stdout


def test_devices_marks_the_chosen_device():
    out = run_cli("devices")
    assert out.returncode == 0, out.stderr
    marked = [line for line in out.stdout.splitlines() if line.startswith("*")]
    assert len(marked) == 1 and "|" in marked[0]
    assert "float atomics" in out.stdout          # each device's capabilities


def test_render_builtin_scene_from_a_ply(tmp_path, rng, capsys):
    ply = tmp_path / "model.ply"
    write_ply(ply, random_model(rng, 2000, sh_degree=1, spread=1.5))
    out = tmp_path / "out"
    assert main(["render", "--ply", str(ply), "--out", str(out), "-r", "2", "--profile"]) == 0
    pngs = sorted((out / "test" / "renders").glob("*.png"))
    assert len(pngs) == 4
    image = read_image(pngs[0])
    assert image.shape == (72, 96, 3) and image.std() > 0.01
    assert "rasterize" in capsys.readouterr().out
    assert [p.name for p in out.iterdir()] == ["test"]   # no staging folder left behind
    # --split all: train and test views each in their own folder (Blender scenes reuse names across splits)
    assert main(["render", "--ply", str(ply), "--out", str(out), "-r", "4", "--split", "all"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["test", "train"]
    assert len(list((out / "train" / "renders").glob("*.png"))) == 28
    assert read_image(sorted((out / "test" / "renders").glob("*.png"))[0]).shape == (36, 48, 3)   # replaced whole


def nan_ply(tmp_path, rng):
    model = random_model(rng, 50, sh_degree=0)
    model.means[7, 1] = np.nan
    path = tmp_path / "nan.ply"
    write_ply(path, model)
    return path


def garbage_ply(tmp_path, rng):
    path = tmp_path / "garbage.ply"
    path.write_bytes(rng.bytes(300))
    return path


@pytest.mark.parametrize("case", ["missing ply", "nan ply", "garbage ply", "missing scene", "vanishing -r"])
def test_bad_input_exits_2_names_the_file_and_writes_nothing(tmp_path, rng, capsys, case):
    out = tmp_path / "out"
    good_ply = tmp_path / "good.ply"
    write_ply(good_ply, random_model(rng, 20, sh_degree=0))
    args, named = {
        "missing ply": (["--ply", str(tmp_path / "nope.ply")], "nope.ply"),
        "nan ply": (["--ply", str(nan_ply(tmp_path, rng))], "nan.ply"),
        "garbage ply": (["--ply", str(garbage_ply(tmp_path, rng))], "garbage.ply"),
        "missing scene": (["--ply", str(good_ply), "--scene", str(tmp_path / "no_scene")], "no_scene"),
        "vanishing -r": (["--ply", str(good_ply), "-r", "1000"], "vanish"),
    }[case]
    assert main(["render", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0] and err[0].startswith("dc4gs-cl render: error:")
    assert not (out / "test").exists()
