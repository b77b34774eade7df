"""Training end to end on the built-in scene: it learns, it resumes to the same result after Ctrl-C or a
crash, and bad settings are refused without touching earlier output."""
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dc4gs_cl.cli import main
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.constants import CARRY_OVERFLOWED, PAIRS_OVERFLOWED
from dc4gs_cl.densify import DC4GSConfig
from dc4gs_cl.evaluation.metrics import psnr
from dc4gs_cl.run_folder import CHECKPOINT, LOCK, RunFolder
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.train import Trainer
from dc4gs_cl.train.schedule import Schedule

SMALL = ["--scene", "builtin", "-r", "2", "--no-progress"]


@pytest.mark.parametrize("low_memory", [False, True], ids=["pair-slots", "atomics"])
def test_training_improves_the_test_views(rt, tmp_path, low_memory):
    scene = load_scene("builtin", resolution=2)
    cfg = TrainConfig(scene="builtin", iterations=600, resolution=2, low_memory=low_memory)
    trainer = Trainer(cfg, scene, rt, tmp_path)
    assert trainer.renderer.tuning.pair_sums is not low_memory

    def test_psnr():
        return np.mean([psnr(trainer.renderer.render(trainer.params, c, trainer.sh_degree, scene.background).image(rt),
                             scene.image(c)) for c in scene.test])

    before = test_psnr()
    trainer.run(progress="none")
    after = test_psnr()
    assert after > before + 6, (before, after)       # measured: 16.2 -> 27.6 dB
    assert trainer.params.n > len(scene.points)      # densified
    assert all(np.isfinite(a).all() for a in trainer.params.download().values())


def test_opacity_reset_limits_opacities_and_restarts_only_their_moments(rt, tmp_path):
    scene = load_scene("builtin", resolution=4)
    trainer = Trainer(TrainConfig(scene="builtin", resolution=4), scene, rt, tmp_path)   # no reset in 3 steps
    for _ in range(3):
        trainer.step()
    adam = trainer.model.adam
    before = {k: adam.m.download_group(k) for k in trainer.model.widths}
    assert np.abs(before["opacity_logits"]).max() > 0
    trainer.model.limit_opacity(0.01)
    o = 1 / (1 + np.exp(-trainer.params.download_group("opacity_logits")))
    assert o.max() <= 0.01 + 1e-6
    np.testing.assert_array_equal(adam.m.download_group("opacity_logits"), 0)
    np.testing.assert_array_equal(adam.v.download_group("opacity_logits"), 0)
    np.testing.assert_array_equal(adam.m.download_group("means"), before["means"])


def cli(*args, wait=True):
    cmd = [sys.executable, "-m", "dc4gs_cl", "train", *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if wait:
        proc.communicate(timeout=300)
    return proc


def final_ply(out: Path, iterations: int) -> bytes:
    return (out / "point_cloud" / f"iteration_{iterations}" / "point_cloud.ply").read_bytes()


@pytest.fixture(scope="module")
def straight_run(tmp_path_factory):
    straight = tmp_path_factory.mktemp("straight")
    assert cli(*SMALL, *INTERRUPTED_RUN, "--out", str(straight)).returncode == 0
    return straight


INTERRUPTED_RUN = ["--iterations", "240", "--checkpoint-every", "40", "--random-background"]   # its draws resume too
STOPS = {"sigint": (signal.SIGINT, 130), "sigterm": (signal.SIGTERM, 143), "sigusr1": (signal.SIGUSR1, 138),
         "kill": (signal.SIGKILL, -signal.SIGKILL)}


@pytest.mark.parametrize("how", list(STOPS))
def test_interrupted_run_resumes_to_the_same_model(straight_run, tmp_path, how):
    """Ctrl-C, SIGTERM (what job schedulers send) and SIGUSR1 (what MPI launchers forward) write a checkpoint and
    exit cleanly; a killed run resumes from its last periodic checkpoint."""
    stopped = tmp_path / "stopped"
    proc = cli(*SMALL, *INTERRUPTED_RUN, "--out", str(stopped), wait=False)
    deadline = time.time() + 120
    while not (stopped / CHECKPOINT).exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    signum, returncode = STOPS[how]
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == returncode, err
    if how != "kill":
        assert f"{signal.Signals(signum).name} at iteration" in err and "--resume" in err
    with np.load(stopped / CHECKPOINT) as f:
        at = json.loads(bytes(f["meta"]).decode())["iteration"]
    assert 0 < at < 240
    resumed = cli("--out", str(stopped), "--resume", "--no-progress")
    assert resumed.returncode == 0
    # Training is deterministic (no float atomics), so the resumed run ends bit for bit where the straight one does.
    assert final_ply(stopped, 240) == final_ply(straight_run, 240)
    # ... and its metrics file holds each iteration once, as the straight run's: the rows an interrupted run
    # wrote after its checkpoint were cut back when it resumed.
    def comparable(rows):
        return [{k: v for k, v in r.items() if k not in ("it_per_s", "elapsed_s", "stage_ms")} for r in rows]
    resumed_rows, straight_rows = RunFolder(stopped).read_metrics(), RunFolder(straight_run).read_metrics()
    assert comparable(resumed_rows) == comparable(straight_rows)
    elapsed = [r["elapsed_s"] for r in resumed_rows if "elapsed_s" in r]
    assert elapsed == sorted(elapsed)                                   # the training clock goes on across the resume


def test_metrics_file_and_progress_lines_off_a_terminal(straight_run, tmp_path):
    """Every run writes metrics.jsonl: a sample every 10 iterations, the test views at the scaled 7,000 and at
    the end. Off a terminal (a pipe here) progress is one line every --log-every iterations, no bar redraws."""
    rows = RunFolder(straight_run).read_metrics()
    samples = [r for r in rows if "loss" in r]
    assert [r["iteration"] for r in samples] == list(range(10, 241, 10))
    assert all(np.isfinite([r["loss"], r["train_psnr"], r["it_per_s"]]).all() and r["gaussians"] > 0 for r in samples)
    assert [r["iteration"] for r in rows if "test_psnr" in r] == [56, 240]      # 7,000 of 30,000 scaled to 240
    assert all(set(r["stage_ms"]) >= {"project", "rasterize", "rasterize_backward"} for r in samples)
    out = tmp_path / "o"
    proc = subprocess.run([sys.executable, "-m", "dc4gs_cl", "train", "--scene", "builtin", "-r", "4", "--iterations",
                           "60", "--log-every", "20", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    err = proc.stderr
    assert "\r" not in err
    assert [int(line.split()[1].split("/")[0]) for line in err.splitlines()
            if line.startswith("iteration ") and "/" in line] == [20, 40, 60]


def snapshot(folder: Path) -> dict:
    """Every output's time and size (the lock file aside: each run into the folder takes it and names itself)."""
    return {str(p): (p.stat().st_mtime_ns, p.stat().st_size) for p in folder.rglob("*") if p.name != LOCK}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    assert main(["train", *SMALL, "-r", "4", "--iterations", "20", "--out", str(out)]) == 0
    return out


def bad(capsys, *args) -> str:
    assert main(["train", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dc4gs-cl train: error:")
    return err[0]


def test_refuses_a_folder_holding_another_run(finished_run, capsys):
    before = snapshot(finished_run)
    assert "holds another run" in bad(capsys, *SMALL, "--iterations", "20", "--out", str(finished_run))
    assert snapshot(finished_run) == before


@pytest.mark.parametrize("kept", ["config.json", "checkpoint.npz"])
def test_a_run_that_cannot_be_resumed_names_the_one_flag_that_works(finished_run, tmp_path, capsys, kept):
    """A run killed after config.json and before its first checkpoint (or a folder with only checkpoint.npz): the
    plain command said "continue it with --resume", --resume "nothing to resume". Both now name --force, which
    works."""
    import shutil
    run = tmp_path / "killed"
    run.mkdir()
    shutil.copy(finished_run / kept, run / kept)
    plain = bad(capsys, *SMALL, "--iterations", "4", "--test-every", "0", "--out", str(run))
    assert "cannot be resumed" in plain and kept in plain and plain.endswith("replace it with --force")
    resumed = bad(capsys, "--out", str(run), "--resume")
    assert "nothing to resume" in resumed and resumed.endswith("replace what it holds with --force")
    assert main(["train", *SMALL, "--iterations", "4", "--test-every", "0", "--out", str(run), "--force"]) == 0
    capsys.readouterr()
    assert "nothing to resume" in bad(capsys, "--out", str(tmp_path / "empty"), "--resume")


def test_corrupt_and_mismatched_checkpoints(finished_run, tmp_path, capsys):
    import shutil
    run = tmp_path / "copy"
    shutil.copytree(finished_run, run)
    (run / CHECKPOINT).write_bytes(os.urandom(500))
    assert "checkpoint.npz" in bad(capsys, "--out", str(run), "--resume")
    shutil.copy(finished_run / CHECKPOINT, run / CHECKPOINT)
    cfg = json.loads((run / "config.json").read_text())
    cfg["seed"] = 7
    (run / "config.json").write_text(json.dumps(cfg))
    assert "other settings" in bad(capsys, "--out", str(run), "--resume")
    assert "differ" in bad(capsys, "--out", str(finished_run), "--resume", "--strategy", "absgs")


@pytest.mark.parametrize("args, says", [
    (["--iterations", "0"], "--iterations 0"),
    (["--iterations", "100", "--save-at", "50", "500"], "--save-at"),
    (["--densify-until", "-5"], "--densify-until"),
    (["--test-every", "-1"], "--test-every"),
    (["--split-threshold", "0"], "--split-threshold 0.0 must be a positive number"),
    (["--split-threshold", "nan"], "--split-threshold nan must be"),
    (["--checkpoint-every", "0"], "--checkpoint-every"),
    (["--resume"], "--resume needs --out"),
    (["--dc4gs", "--split-candidates", "4"], "--split-candidates 4"),
    (["--split-candidates", "1"], "--split-candidates 1"),      # checked even with DC4GS off
    (["--dcs", "--dcs-track", "1.5"], "--dcs-track 1.5"),
    (["--dcs", "--dcs-other-scale", "0"], "--dcs-other-scale 0.0 must lie in (0, 1]"),
    (["--dcs", "--dcs-every", "0"], "--dcs-every 0 must be at least 1"),
    (["--dc4gs", "--dc-pooling", "window", "--dcs-every", "2"], "--dcs-every 2 needs --dc-pooling view"),
    (["--sh-degree", "4"], "--sh-degree 4"),
    (["--max-gaussians", "0"], "--max-gaussians 0 must be at least 1"),
    (["--max-gaussians", "100"], "--max-gaussians 100 is below the"),
    (["--white-background"], "built-in scene"),
    (["--split-candidates", "101"], "--split-candidates 101 must be odd, 3..99"),   # 10,001 crashed PoCL
    (["--dc4gs", "--split-candidates", "10001"], "--split-candidates 10001"),
    (["--seed", "-1"], "--seed -1 must be 0..2^63-1"),                             # was a traceback
    (["--seed", str(2 ** 63)], "--seed 9223372036854775808 must be"),
    (["--lambda-dssim", "1.5"], "--lambda-dssim 1.5 must lie in [0, 1]"),
    (["--opacity_lr", "-1"], "--opacity-lr -1.0 must be a finite number >= 0"),
    (["--position-lr-init", "nan"], "--position-lr-init nan must be a finite number"),
    (["--densification-interval", "0"], "--densification-interval 0 must be >= 1"),
    (["--opacity-reset-interval", "-3"], "--opacity-reset-interval -3 must be >= 0"),
])
def test_settings_that_make_no_sense(tmp_path, capsys, args, says):
    out = [] if "--resume" in args else ["--out", str(tmp_path / "o")]
    assert says in bad(capsys, *SMALL, *args, *out)
    assert not (tmp_path / "o").exists()


def test_max_gaussians_caps_every_densification_step(rt, tmp_path):
    scene = load_scene("builtin", resolution=4)
    start = len(scene.points)
    cap = start + 150
    trainer = Trainer(TrainConfig(scene="builtin", iterations=400, resolution=4, max_gaussians=cap),
                      scene, rt, tmp_path)
    peak = 0
    while trainer.iteration < 400:
        trainer.step()
        peak = max(peak, trainer.model.n)
    assert cap - 20 <= peak <= cap           # it grows to the cap (pruning may take a few) and never past it


def test_interpolated_test_views_and_per_view_results(tmp_path, capsys):
    """--test-split is saved with the run, so eval scores the same held-out views; train and eval print every
    view's PSNR and SSIM (worst first) beside the means."""
    out = tmp_path / "run"
    assert main(["train", *SMALL, "-r", "4", "--iterations", "20", "--test-split", "interpolated",
                 "--out", str(out)]) == 0
    trained = capsys.readouterr().out
    assert main(["eval", "--model", str(out)]) == 0
    evaluated = capsys.readouterr().out
    psnrs = json.loads((out / "per_view.json").read_text())["ours_20"]["PSNR"]
    assert sorted(psnrs) == ["view_004.png", "view_012.png", "view_020.png", "view_028.png"]
    for printed in (trained, evaluated):
        rows = [line.split() for line in printed.splitlines() if line.startswith("  view_")]
        assert [r[0] for r in rows] == sorted(psnrs, key=psnrs.get)
        assert [float(r[2]) for r in rows] == [round(psnrs[r[0]], 2) for r in rows]


def test_split_threshold_replaces_the_strategys(rt, tmp_path):
    """--split-threshold is the threshold the strategy splits on (DCS' tracking threshold follows it); a run
    whose threshold no criterion reaches splits nothing where the default splits, and clones as before."""
    cfg = TrainConfig(scene="builtin", strategy="absgs", split_threshold=1e-3,
                      dc4gs=DC4GSConfig(dcc=True, dcs=True, track=0.5))
    strategy = Schedule(cfg).strategy()
    assert strategy.config.split_threshold == 1e-3 and strategy.track_threshold == 5e-4
    assert Schedule(replace(cfg, split_threshold=None)).strategy().config.split_threshold == 4e-4
    scene = load_scene("builtin", resolution=4)
    reports = {}
    for threshold in (None, 1e6):
        trainer = Trainer(TrainConfig(scene="builtin", iterations=300, resolution=4, split_threshold=threshold),
                          scene, rt, tmp_path / str(threshold))
        apply, reports[threshold] = trainer.strategy.apply, []
        trainer.strategy.apply = lambda *a, apply=apply, into=reports[threshold]: into.append(apply(*a)) or into[-1]
        while trainer.iteration < 300:
            trainer.step()
    done = {t: [r for r in rs if r is not None] for t, rs in reports.items()}
    assert len(done[None]) == len(done[1e6]) > 3
    assert sum(r.split for r in done[None]) > 0 and sum(r.split for r in done[1e6]) == 0
    assert sum(r.cloned for r in done[1e6]) > 0


def test_recipe_settings_reach_the_schedule_and_the_loss(rt):
    """The recipe's flags: the schedule's steps as given (not scaled to the run), no opacity reset with 0, the
    loss' SSIM weight, the higher SH bands' rate 1/20 of --feature-lr as in the Inria code unless given."""
    cfg = TrainConfig(scene="builtin", iterations=3000, resolution=4, densify_from=40, densify_every=30,
                      opacity_reset_every=0, densify_until=900, lambda_dssim=0.4)
    strategy = Schedule(cfg).strategy()
    c = strategy.config
    assert (c.densify_from, c.densify_every, c.opacity_reset_every, c.densify_until) == (40, 30, 0, 900)
    assert not any(strategy.reset_opacity_now(it, False) for it in range(1, 3001))
    default = Schedule(replace(cfg, densify_from=None, densify_every=None, opacity_reset_every=None)).strategy().config
    assert (default.densify_from, default.densify_every, default.opacity_reset_every) == (50, 100, 300)   # scaled
    assert Trainer(cfg, load_scene("builtin", resolution=4), rt).loss.lambda_dssim == 0.4
    from dc4gs_cl.apps.train import train_config
    from dc4gs_cl.cli import build_parser
    for flags, rest in ((["--feature_lr", "0.004"], 0.004 / 20),
                        (["--feature-lr", "0.004", "--feature-rest-lr", "1e-4"], 1e-4)):
        args = build_parser().parse_args(["train", *flags])
        assert train_config(args, None).lr_sh_rest == rest and train_config(args, None).lr_sh_dc == 0.004


def test_random_background_draws_a_colour_each_iteration_from_the_seed(rt):
    """--random-background renders each iteration onto a colour drawn from the run's generator: the same seed,
    the same colours and the same model; without it, the scene's background every time."""
    scene = load_scene("builtin", resolution=4)
    runs = {}
    for name, random_background in (("a", True), ("b", True), ("off", False)):
        trainer = Trainer(TrainConfig(scene="builtin", iterations=30, resolution=4,
                                      random_background=random_background), scene, rt)
        render, runs[name] = trainer.renderer.render, []
        trainer.renderer.render = lambda p, c, sh, bg, *a, render=render, into=runs[name]: \
            into.append(np.array(bg)) or render(p, c, sh, bg, *a)
        for _ in range(30):
            trainer.step()
        runs[name] = (np.array(runs[name]), trainer.model.download().params)
    colours = runs["a"][0]   # a view that overflowed its room runs again: with the colour drawn for it before
    assert len(np.unique(colours, axis=0)) == 30 and 0 <= colours.min() <= colours.max() <= 1
    np.testing.assert_array_equal(colours, runs["b"][0])
    assert all(np.array_equal(runs["a"][1][k], runs["b"][1][k]) for k in runs["a"][1])
    assert (runs["off"][0] == scene.background).all()


def test_a_trainer_without_a_run_folder_steps_and_says_what_needs_one(rt):
    """Benchmarks step a trainer made without a run folder; what reads or writes one says that it needs one."""
    scene = load_scene("builtin", resolution=4)
    trainer = Trainer(TrainConfig(scene="builtin", iterations=50, resolution=4, save_at=(2,)), scene, rt)
    trainer.step()
    with pytest.raises(RuntimeError, match="saving a model needs a run folder"):
        trainer.step()                                    # --save-at 2
    for needs_one in (trainer.save_checkpoint, trainer.resume, lambda: trainer.run(progress="none")):
        with pytest.raises(RuntimeError, match="needs a run folder, and this trainer was made without one"):
            needs_one()

def test_a_saved_iteration_precedes_its_opacity_reset(rt, tmp_path):
    """--save-at N writes the model after iteration N's optimiser step and before its density control (as
    the Inria code saves), so a PLY saved at a reset iteration is not the reset, transparent model."""
    from dc4gs_cl.ply import read_ply
    scene = load_scene("builtin", resolution=2)
    trainer = Trainer(TrainConfig(scene="builtin", iterations=600, resolution=2, save_at=(60,)), scene, rt, tmp_path)
    assert trainer.strategy.reset_opacity_now(60, False)
    while trainer.iteration < 60:
        trainer.step()
    sigmoid = lambda x: 1 / (1 + np.exp(-x))
    saved = sigmoid(read_ply(tmp_path / "point_cloud" / "iteration_60" / "point_cloud.ply").opacity_logits)
    now = sigmoid(trainer.params.download_group("opacity_logits"))
    assert now.max() < 0.0101 and saved.max() > 0.05, (now.max(), saved.max())


def test_check_finite_names_stage_iteration_and_buffer(rt, tmp_path):
    """--check-finite: a NaN injected into the parameters stops the next iteration at the first stage that writes
    it (the forward's clamps keep it out of the image; the optimiser step writes the parameter back), one
    injected into the target image at the loss's gradient; each error names stage, iteration and buffer."""
    from dataclasses import replace

    from dc4gs_cl.finite import NonFiniteError
    scene = load_scene("builtin", resolution=4)
    cfg = TrainConfig(scene="builtin", iterations=50, resolution=4, densify_until=0)
    trainer = Trainer(cfg, scene, rt, tmp_path, check_finite=True)
    for _ in range(3):
        trainer.step()                                    # finite: nothing stops
    logits = trainer.params.download_group("opacity_logits")
    trainer.params.upload_group("opacity_logits", np.where(np.arange(len(logits))[:, None] % 7 == 0, np.nan, logits))
    with pytest.raises(NonFiniteError, match=r"iteration 4: stage project_backward wrote .* in opacity_logits") as e:
        trainer.step()
    assert (e.value.stage, e.value.buffer, e.value.at) == ("project_backward", "opacity_logits", "iteration 4")

    def nan_image(cam):                                    # every fifth column of the target NaN
        image = np.full((cam.height, cam.width, 3), 0.5, np.float32)
        image[:, ::5] = np.nan
        return image
    nan_scene = replace(scene, read_image=nan_image)
    trainer = Trainer(cfg, nan_scene, rt, tmp_path, check_finite=True)
    with pytest.raises(NonFiniteError, match="iteration 1: stage loss") as e:
        trainer.step()
    assert e.value.buffer == "dL_dimage"
    off = Trainer(cfg, nan_scene, rt, tmp_path)
    off.step()                                             # off: the same NaN passes unnoticed


def test_check_finite_on_the_command_line(tmp_path):
    out = tmp_path / "run"
    assert main(["train", *SMALL, "-r", "4", "--iterations", "12", "--check-finite", "--out", str(out)]) == 0
    assert main(["render", "--model", str(out), "--check-finite"]) == 0
    assert sorted(p.name for p in (out / "test" / "ours_12").iterdir()) == ["gt", "renders"]


@pytest.mark.parametrize("strategy, walk, batch", [("3dgs", "one run", 1), ("absgs+dc4gs", "one run", 1),
                                                   ("absgs+dc4gs", "runs", 1), ("absgs+dc4gs", "one run", 2)])
def test_a_view_that_overflows_its_room_runs_again_to_the_same_model(rt, monkeypatch, strategy, walk, batch):
    """The trainer sizes a view's pair buffers by a capacity, and the backward's carry rows (for the Gaussians
    whose pairs span its runs) by another, and waits for nothing until the iteration is queued; a view with more
    changes nothing on the device and runs again with room (in a batch, before the batch's next view). Forced here
    every few iterations (a densification step among them): the model, its moments and the window are those of a
    run that never overflowed, bit for bit."""
    from dc4gs_cl.render import Tuning
    if walk == "runs":   # each view's backward in several runs of consecutive pairs, the window folded in them
        for_device = Tuning.for_device
        monkeypatch.setattr(Tuning, "for_device", staticmethod(
            lambda caps: replace(for_device(caps), pair_chunk=0.3, min_run_tiles=4)))
    scene = load_scene("builtin", resolution=4)
    cfg = TrainConfig(scene="builtin", iterations=300, resolution=4, strategy=strategy.split("+")[0], batch=batch,
                      dc4gs=DC4GSConfig(dcc=True, dcs=True) if "dc4gs" in strategy else DC4GSConfig())
    steady, forced = Trainer(cfg, scene, rt), Trainer(cfg, scene, rt)
    overflows = []
    overflowed = forced._overflowed   # each view's counts, as the trainer takes them

    def counted(read):
        overflows.append(read.result()["OVERFLOWED"])
        return overflowed(read)
    monkeypatch.setattr(forced, "_overflowed", counted)
    densify_at = [it for it in range(1, 201) if steady.strategy.actions(it).densify]
    assert densify_at, "the test wants a densification step to overflow"
    for it in range(1, 201):
        steady.step()
        if it % 7 == 0 or it == densify_at[0]:
            forced.pair_capacity = 1
        elif it % 5 == 0:
            forced.carry_rows = 1
        forced.step()
    assert overflows.count(PAIRS_OVERFLOWED) >= 200 // 7 and forced.model.n == steady.model.n > len(scene.points)
    if walk == "runs":   # views in runs, carrying sums: most of those given one row overflowed it
        assert overflows.count(CARRY_OVERFLOWED) >= 200 // 5 // 2
    else:
        assert CARRY_OVERFLOWED not in overflows   # one run: no carry
    a, b = steady.model.download(), forced.model.download()
    for what, mine, theirs in [("params", a.params, b.params), ("m", a.m, b.m), ("v", a.v, b.v),
                               ("window", steady.strategy.window.download(), forced.strategy.window.download())]:
        for name in mine:
            np.testing.assert_array_equal(mine[name], theirs[name], err_msg=f"{what} {name}")
    assert steady.loss.read_stats() == forced.loss.read_stats()


@pytest.mark.parametrize("walk", ["one run", "runs"])
def test_the_views_counts_are_read_where_they_are_final_not_after_the_backward(rt, monkeypatch, walk):
    """The iteration's one wait is for the view's counts alone: their read is queued after every kernel that
    counts or overflows (the intersection, its sorts and scans, run_spans where the view is walked in runs) and
    before the loss, so that the device runs the loss and the backward while the host queues the next iteration;
    and it is the only read of the iteration."""
    from dc4gs_cl.render import Tuning
    if walk == "runs":
        for_device = Tuning.for_device
        monkeypatch.setattr(Tuning, "for_device", staticmethod(
            lambda caps: replace(for_device(caps), pair_chunk=0.3, min_run_tiles=4)))
    scene = load_scene("builtin", resolution=4)
    cfg = TrainConfig(scene="builtin", iterations=300, resolution=4, strategy="absgs",
                      dc4gs=DC4GSConfig(dcc=True, dcs=True))
    trainer = Trainer(cfg, scene, rt)
    for _ in range(3):   # the pair room and carry rows sized
        trainer.step()
    queued = []
    launch, read_later = rt.launch, rt.to_host_later
    monkeypatch.setattr(rt, "launch", lambda stage, kernel, *a: queued.append((stage, kernel.function_name))
                        or launch(stage, kernel, *a))
    monkeypatch.setattr(rt, "to_host_later", lambda *a: queued.append(("read", "")) or read_later(*a))
    syncs = rt.syncs
    trainer.step()
    assert rt.syncs - syncs == 1 and queued.count(("read", "")) == 1
    at = queued.index(("read", ""))
    before, after = {s for s, _ in queued[:at]}, queued[at + 1:]
    assert {"project", "isect", "sort"} <= before
    assert (("sum_pairs", "run_spans") in queued[:at]) == (walk == "runs")
    assert not {s for s, k in after if s in ("isect", "sort") or k == "run_spans"}, after
    assert after[0][0] == "loss" and {"rasterize_backward", "sum_pairs", "project_backward"} <= {s for s, _ in after}


@pytest.mark.parametrize("low_memory", [False, True], ids=["pair-slots", "atomics"])
def test_a_void_frame_changes_nothing_on_the_device(rt, low_memory):
    """Every kernel that changes lasting state leaves it as it was in a frame marked overflowed (FRAME_VOID): the
    parameters, Adam's moments, the window (sum_pairs' fold, or the window's own kernel with --low-memory, whose
    float atomics are not bit-reproducible: the trainer test above cannot cover it) and the loss' sums."""
    from dc4gs_cl.constants import FRAME_WORDS
    void = np.array([word == "OVERFLOWED" for word in FRAME_WORDS], np.uint32)
    scene = load_scene("builtin", resolution=4)
    cfg = TrainConfig(scene="builtin", iterations=300, resolution=4, strategy="absgs",
                      dc4gs=DC4GSConfig(dcc=True, dcs=True), low_memory=low_memory)
    trainer = Trainer(cfg, scene, rt)
    for _ in range(3):
        trainer.step()
    before = trainer.model.download(), trainer.strategy.window.download(), trainer.loss.running_sums()[0]
    queue = trainer._queue_iteration

    def void_frame():   # the view queued as usual, its frame then marked overflowed before the backward runs (once)
        render = trainer.renderer.render

        def marked(*args):
            res = render(*args)
            rt.write(trainer.context.frame, void)
            return res
        trainer.renderer.render = marked
        trainer._overflowed = lambda read: read.result() is None   # its counts waited for, the view not run again
        try:
            return queue()
        finally:
            trainer.renderer.render = render
            del trainer._overflowed

    void_frame()
    after = trainer.model.download(), trainer.strategy.window.download(), trainer.loss.running_sums()[0]
    for mine, theirs in [(before[0].params, after[0].params), (before[0].m, after[0].m), (before[0].v, after[0].v),
                         (before[1], after[1])]:
        for name in mine:
            np.testing.assert_array_equal(mine[name], theirs[name], err_msg=name)
    assert before[2] == after[2]


def test_the_most_split_candidates_train_and_learning_rates_are_bounded(rt):
    """--split-candidates at its bound (config.MAX_CANDIDATES) trains; a config.json with a learning rate that is
    negative or not finite is refused naming its flag."""
    from dc4gs_cl.config import MAX_CANDIDATES
    from dc4gs_cl.errors import InputError
    scene = load_scene("builtin", resolution=8)
    cfg = TrainConfig(scene="builtin", iterations=20, resolution=8, strategy="absgs",
                      dc4gs=DC4GSConfig(dcc=True, dcs=True, split_pick="dense", candidates=MAX_CANDIDATES))
    from dc4gs_cl.apps.bench import frozen_trainer
    start = Trainer(cfg, scene, rt).model.download()
    trainer = frozen_trainer(cfg, scene, rt, start, 0, split_costs_for_all=True)   # every Gaussian's costs gathered
    for _ in range(3):
        trainer.step()
    assert all(np.isfinite(a).all() for a in trainer.params.download().values())
    costs = trainer.strategy.window.download()["split_costs"]
    assert costs.shape[1] == MAX_CANDIDATES and np.count_nonzero(costs) > 1000 and np.isfinite(costs).all()
    for rate in (-1.0, float("inf")):
        with pytest.raises(InputError, match=f"--opacity-lr {rate} must be a finite number >= 0"):
            replace(cfg, lr_opacity=rate)
