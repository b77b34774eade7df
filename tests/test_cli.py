"""The command line: help, devices, render, and bad input (exit code 2, the file named, no output); every
command loads a run's scene and settings as the run trained."""
import argparse
import shutil
import subprocess
import sys

import numpy as np
import pytest
from helpers import load_tool

from dc4gs_cl.apps import viewer
from dc4gs_cl.apps.train import train_config
from dc4gs_cl.cli import build_parser, main
from dc4gs_cl.config import DC4GSConfig, MCMCConfig, TrainConfig
from dc4gs_cl.files import write_json
from dc4gs_cl.ply import write_ply
from dc4gs_cl.run_folder import RunFolder
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.images import read_image
from dc4gs_cl.reference.testing import random_model


def run_cli(*args) -> subprocess.CompletedProcess:
    exe = shutil.which("dc4gs-cl") or sys.executable
    cmd = [exe, *args] if exe.endswith("dc4gs-cl") else [exe, "-m", "dc4gs_cl", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def test_help_lists_the_commands():
    out = run_cli("--help")
    assert out.returncode == 0
    for command in ("devices", "render", "train", "eval", "view", "export", "report", "sfm"):
        assert command in out.stdout
    assert "With no command, dc4gs-cl runs `dc4gs-cl train`" in " ".join(out.stdout.split())   # the bare command
    from dc4gs_cl import __version__
    version = run_cli("--version")
    assert version.returncode == 0 and version.stdout.strip() == f"dc4gs-cl {__version__}"


def test_a_reader_that_leaves_early_ends_the_command_quietly():
    """`dc4gs-cl eval ... | head`: the closed pipe ends the command with 141, as a pipe stage, no traceback."""
    code = ("import sys\nfrom dc4gs_cl import cli\n"
            "cli.COMMANDS['devices'] = lambda args: [print('x' * 1000) for _ in range(10 ** 4)] and 0\n"
            "sys.exit(cli.main(['devices']))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.read(10)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141 and err == "", err


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


def test_a_run_trained_antialiased_renders_antialiased(tmp_path, rng, capsys):
    """--antialiased is the model's mode: config.json records it, render and eval use it, render
    --no-antialiased (or a PLY without --antialiased) does not; the renders differ only by the opacities."""
    run = tmp_path / "run"
    assert main(["train", "--out", str(run), "--iterations", "30", "-r", "4", "--no-progress", "--lpips", "none",
                 "--antialiased"]) == 0
    assert RunFolder(run).read_config().antialiased
    renders = {}
    for name, flags in (("run", []), ("off", ["--no-antialiased"])):
        assert main(["render", "--model", str(run), "--out", str(tmp_path / name), *flags]) == 0
        renders[name] = read_image(sorted((tmp_path / name / "test" / "renders").glob("*.png"))[0])
    ply = next(run.glob("point_cloud/iteration_30/*.ply"))
    for name, flags in (("ply", []), ("ply-aa", ["--antialiased"])):
        assert main(["render", "--ply", str(ply), "--out", str(tmp_path / name), "-r", "4", *flags]) == 0
        renders[name] = read_image(sorted((tmp_path / name / "test" / "renders").glob("*.png"))[0])
    assert np.array_equal(renders["run"], renders["ply-aa"]) and np.array_equal(renders["off"], renders["ply"])
    assert np.abs(renders["run"] - renders["off"]).max() > 0.02
    # .spz records the mode in its header (export of the run sets it; render of the file follows it); a PLY
    # export says it cannot
    from dc4gs_cl.apps.export import cmd_export, read_model_file, recorded_antialiased
    for name in ("m.spz", "m.ply"):
        assert cmd_export(argparse.Namespace(model=run, ply=None, iteration=None, out=tmp_path / name,
                                             format=None)) == 0
    assert recorded_antialiased(tmp_path / "m.spz") is True and recorded_antialiased(tmp_path / "m.ply") is None
    assert "cannot record" in capsys.readouterr().out
    write_ply(tmp_path / "spz-read.ply", read_model_file(tmp_path / "m.spz"))
    for name, source, flags in (("spz", "m.spz", []), ("spz-ply-aa", "spz-read.ply", ["--antialiased"])):
        assert main(["render", "--ply", str(tmp_path / source), "--out", str(tmp_path / name), "-r", "4", *flags]) == 0
        renders[name] = read_image(sorted((tmp_path / name / "test" / "renders").glob("*.png"))[0])
    assert np.array_equal(renders["spz"], renders["spz-ply-aa"])


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


class SceneLoaded(Exception):
    """Stops a command once it has its scene, before it needs a device."""


def test_every_command_loads_a_runs_scene_as_it_trained(tmp_path, rng, monkeypatch):
    """render, eval, view, train and tools/bench_export load a run's scene through RunFolder.load_scene: its
    test views (here interpolated) and its alpha masks, which render and the viewer once dropped."""
    fuzz_inputs = load_tool("fuzz_inputs")
    fuzz_inputs.nerf_scene(tmp_path / "scene", rng, channels=4)
    cfg = TrainConfig(scene=str(tmp_path / "scene"), iterations=10, test_split="interpolated", alpha_mask=True)
    run = RunFolder(tmp_path / "run")
    write_json(run.config_path, cfg.to_json())
    run.save_model(cfg.iterations, random_model(rng, 20, sh_degree=0))
    expected = load_scene(cfg.scene, test_split="interpolated", alpha_mask=True)
    assert [c.name for c in expected.test] != [c.name for c in load_scene(cfg.scene).test]   # not llff's views
    loaded, load = [], RunFolder.load_scene

    def loading(self, *args, **kwargs):
        loaded.append(load(self, *args, **kwargs))
        raise SceneLoaded
    monkeypatch.setattr(RunFolder, "load_scene", loading)
    monkeypatch.setattr(viewer, "_viser", lambda: None)   # the viewer stops at its scene: viser is never used
    for argv in (["render", "--model", str(run)], ["eval", "--model", str(run)], ["view", str(run), "--port", "0"],
                 ["train", "--scene", cfg.scene, "--out", str(tmp_path / "again"), "--test-split", "interpolated",
                  "--alpha-mask"]):
        with pytest.raises(SceneLoaded):
            main(argv)
    with pytest.raises(SceneLoaded):
        load_tool("bench_export").load(argparse.Namespace(ply=None, run=run.path, iteration=None))
    assert len(loaded) == 5
    for scene in loaded:
        assert [c.name for c in scene.test] == [c.name for c in expected.test]
        assert all(scene.mask(c) is not None for c in scene.train)   # the alpha masks


def test_resume_takes_the_flags_the_run_was_started_with(tmp_path):
    """--resume with flags that agree with the saved settings continues them; --dc4gs (DCC and DCS) included."""
    run = RunFolder(tmp_path)
    cfg = TrainConfig(scene="builtin", iterations=100, dc4gs=DC4GSConfig(dcc=True, dcs=True))
    write_json(run.config_path, cfg.to_json())
    args = build_parser().parse_args(["train", "--out", str(tmp_path), "--resume", "--dc4gs", "--iterations", "100"])
    assert train_config(args, run) == cfg


def test_settings_an_older_run_saved_flat_still_load(tmp_path):
    """config.json of runs made before DC4GS' and MCMC's settings were nested (TrainConfig.dc4gs, .mcmc) holds them
    flat, under their flag's key: --resume (with flags that agree) and eval read them as they were."""
    cfg = TrainConfig(scene="builtin", iterations=100, strategy="mcmc", dc4gs=DC4GSConfig(dcs=True, split_pick="dense"),
                      mcmc=MCMCConfig(noise_lr=1e4, opacity_reg=0.02, scale_reg=0.0))
    flat = {k: v for k, v in cfg.to_json().items() if k not in ("dc4gs", "mcmc")}
    flat |= {"dcs": True, "split_pick": "dense", "mcmc_noise_lr": 1e4, "opacity_reg": 0.02, "scale_reg": 0.0}
    run = RunFolder(tmp_path)
    write_json(run.config_path, flat)
    assert run.read_config() == cfg
    args = build_parser().parse_args(["train", "--out", str(tmp_path), "--resume", "--mcmc-noise-lr", "10000",
                                      "--scale-reg", "0"])
    assert train_config(args, run) == cfg


def test_cfg_args_holds_what_is_true_of_the_run(tmp_path, rng):
    """cfg_args (the Inria tools' Namespace) names a scene folder only where there is one, its images folder only
    where that is the scene's, and no CUDA device."""
    builtin = RunFolder(tmp_path / "builtin")
    builtin.write_settings(TrainConfig(scene="builtin"), load_scene("builtin", resolution=8))
    text = (builtin.path / "cfg_args").read_text()
    assert text.startswith("Namespace(sh_degree=3, model_path=") and "eval=True" in text
    assert not any(key in text for key in ("source_path", "images=", "data_device"))
    root = tmp_path / "colmap"
    load_tool("fuzz_inputs").colmap_scene(root, rng, "bin")
    colmap = RunFolder(tmp_path / "run")
    colmap.write_settings(TrainConfig(scene=str(root), resolution=2, test_every=0), load_scene(str(root), resolution=2))
    text = (colmap.path / "cfg_args").read_text()
    assert f"source_path={str(root.resolve())!r}" in text and "images='images'" in text and "resolution=2" in text


def test_differing_settings_are_named_one_by_one_in_the_fields_order():
    """--resume's refusal lists each differing setting, a group's by "<group>.<field>" (not the group's repr), and
    leaves out the settings that do not change the model."""
    a = TrainConfig(scene="builtin", strategy="mcmc")
    b = TrainConfig(scene="builtin", strategy="mcmc", seed=3, save_at=(5,), mcmc=MCMCConfig(noise_lr=1e3),
                    dc4gs=DC4GSConfig(dcs=True))
    assert list(a.differences(b).items()) == [("seed", (0, 3)), ("mcmc.noise_lr", (5e5, 1e3)),
                                              ("dc4gs.dcs", (False, True))]
