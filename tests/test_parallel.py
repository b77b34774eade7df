"""Training on batches of views (--batch B) and in several processes (mpirun -n P dc4gs-cl train): the batch's
rules, a batch run resuming to the same model, and two MPI processes training as one process with a batch of two,
their models the same on both, interrupted and resumed. The MPI tests skip where mpi4py or mpirun is absent."""
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import straight_and_resumed

from dc4gs_cl.config import TrainConfig
from dc4gs_cl.densify import DC4GSConfig
from dc4gs_cl.errors import InputError
from dc4gs_cl.train.parallel import SingleProcess
from dc4gs_cl.run_folder import CHECKPOINT
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.statistics import MAX_COLUMNS, StatisticsSpec
from dc4gs_cl.train import Trainer
from dc4gs_cl.train.schedule import Schedule

MPIRUN = shutil.which("mpirun", path=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
needs_mpi = pytest.mark.skipif(importlib.util.find_spec("mpi4py") is None or MPIRUN is None,
                               reason="mpi4py or mpirun is not installed (pip install '.[mpi]')")


def test_a_batch_scales_the_rates_betas_and_schedule_and_splits_among_processes(rt):
    """Grendel's rule: rates times sqrt(B), Adam's betas to the power B; the schedule in views; a batch that the
    processes cannot share evenly is refused; each process takes a contiguous share."""
    one, four = (Schedule(TrainConfig(scene="builtin", batch=b)).learning_rates(10, 2.0, True) for b in (1, 4))
    assert four["means"] == pytest.approx(2 * one["means"]) and four["sh"] == pytest.approx((2 * one["sh"][0],
                                                                                           2 * one["sh"][1]))
    # the densification interval counts views: a batch of 4 over 7,500 iterations densifies where 30,000 of one do
    for batch, iterations in ((1, 30_000), (4, 7_500)):
        c = Schedule(TrainConfig(scene="builtin", batch=batch, iterations=iterations)).strategy().config
        assert (c.densify_from * batch, c.densify_until * batch, c.densify_every * batch) == (500, 15_000, 100)
    scene = load_scene("builtin", resolution=8)
    trainer = Trainer(TrainConfig(scene="builtin", resolution=8, batch=4), scene, rt)
    assert trainer.model.adam.config.beta1 == pytest.approx(0.9 ** 4)
    assert trainer.model.adam.config.beta2 == pytest.approx(0.999 ** 4)

    class Two(SingleProcess):
        size, rank = 2, 1
    with pytest.raises(InputError, match="--batch 3 must be a multiple of the 2 processes"):
        Trainer(TrainConfig(scene="builtin", resolution=8, batch=3), scene, rt, group=Two())
    assert Two().share(list("abcd")) == ["c", "d"]
    assert not Two().writes


def test_a_batch_run_learns_and_resumes_to_the_same_model(rt, tmp_path):
    """--batch 2 with AbsGS + DC4GS (the window gathered over both views of each step): the test views improve,
    it densifies, and a run stopped at a checkpoint and resumed ends bit for bit where the straight run does."""
    scene = load_scene("builtin", resolution=4)
    cfg = TrainConfig(scene="builtin", resolution=4, iterations=120, batch=2, strategy="absgs",
                      dc4gs=DC4GSConfig(dcc=True, dcs=True))

    straight, resumed = straight_and_resumed(cfg, scene, rt, tmp_path, 50)
    a, b = straight.model.download(), resumed.model.download()
    for name in a.params:
        np.testing.assert_array_equal(a.params[name], b.params[name], err_msg=name)
        np.testing.assert_array_equal(a.m[name], b.m[name], err_msg=name)
    stepping = sum(straight.strategy.actions(it).optimiser_step for it in range(1, 121))   # not on densify steps
    assert straight.model.adam.steps["means"] == stepping > 100 and a.n > len(scene.points)
    assert straight.loss.read_stats()["loss"] < 0.25


def mpi_train(n: int, *args, wait: bool = True) -> subprocess.Popen:
    cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "-n", str(n), sys.executable, "-m", "dc4gs_cl", "train",
           "--no-progress", "--lpips", "none", *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    if wait:
        proc.out, proc.err = proc.communicate(timeout=600)
    return proc


def one_process(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dc4gs_cl", "train", "--no-progress", "--lpips", "none", *args],
                          capture_output=True, text=True, timeout=600)


def model_bytes(out: Path, iterations: int) -> bytes:
    return (out / "point_cloud" / f"iteration_{iterations}" / "point_cloud.ply").read_bytes()


RUN = ["--scene", "builtin", "-r", "4", "--iterations", "150", "--checkpoint-every", "30"]


@pytest.fixture(scope="module")
def two_processes(tmp_path_factory):
    out = tmp_path_factory.mktemp("mpi") / "run"
    proc = mpi_train(2, *RUN, "--out", str(out))
    assert proc.returncode == 0, proc.err
    return out, proc


@needs_mpi
def test_two_processes_train_as_one_process_with_a_batch_of_two(two_processes, tmp_path):
    """mpirun -n 2: a view each per iteration (the batch defaults to the process count), models checked the same on
    both at every checkpoint; the result equals one process's --batch 2 run bit for bit: the gradients of two views
    are added in either order to the same floats, and the windows' sums, added in another order, take the same
    decisions here (they may differ in their last bits: float addition is not associative)."""
    out, proc = two_processes
    assert "2 processes of a batch of 2 views" in proc.err
    assert "gradients summed over 2 processes" in proc.out
    single = tmp_path / "single"
    done = one_process(*RUN, "--batch", "2", "--out", str(single))
    assert done.returncode == 0, done.stderr
    assert model_bytes(out, 150) == model_bytes(single, 150)


@needs_mpi
def test_two_processes_stopped_and_resumed_end_where_they_would_have(two_processes, tmp_path):
    """SIGUSR1 to mpirun alone (Open MPI forwards it; SIGTERM would make it kill the processes a quarter of a second
    later): both processes stop at the same iteration after a checkpoint, mpirun exits as one process does (138)
    with its line; resumed under mpirun they end bit for bit where the uninterrupted run did; one process can
    resume it too."""
    out, _ = two_processes
    stopped = tmp_path / "stopped"
    proc = mpi_train(2, *RUN, "--out", str(stopped), wait=False)
    deadline = time.time() + 300
    while not (stopped / CHECKPOINT).exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGUSR1)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 128 + signal.SIGUSR1, err
    assert "stop: SIGUSR1 to mpirun stops every process after a checkpoint" in err
    with np.load(stopped / CHECKPOINT) as f:
        at = json.loads(bytes(f["meta"]).decode())["iteration"]
    assert f"SIGUSR1 at iteration {at}; a checkpoint is in" in err and "--resume" in err, err
    assert 0 < at < 150
    alone = tmp_path / "alone"
    shutil.copytree(stopped, alone)
    resumed = mpi_train(2, "--out", str(stopped), "--resume")
    assert resumed.returncode == 0, resumed.err
    assert model_bytes(stopped, 150) == model_bytes(out, 150)
    # one process takes the run over (its batch of 2 from config.json): the same state, sums added in its order
    done = one_process("--out", str(alone), "--resume")
    assert done.returncode == 0, done.stderr
    psnr = [json.loads((run / "results.json").read_text())["ours_150"]["PSNR"] for run in (alone, out)]
    assert abs(psnr[0] - psnr[1]) < 0.2, psnr


def test_started_by_a_launcher_without_mpi4py_says_how_to_get_it(monkeypatch):
    """A process an MPI launcher started among several, where mpi4py does not import: one line naming the extra;
    started alone (no launcher's variables, or a world of one), no MPI at all."""
    from dc4gs_cl.train.parallel import SIZE_VARIABLES, process_group
    for name in SIZE_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    assert type(process_group()) is SingleProcess
    monkeypatch.setenv("PMI_SIZE", "1")
    assert type(process_group()) is SingleProcess
    monkeypatch.setenv("PMI_SIZE", "4")
    monkeypatch.setitem(sys.modules, "mpi4py", None)   # import mpi4py raises ImportError
    with pytest.raises(InputError, match=r"one of 4 MPI processes, but mpi4py is not installed: pip install"):
        process_group()


class TwoProcessWorld:
    """What MPIGroup asks of a communicator, as process 0 of two; process 1 sends what other(process 0's) gives."""
    def __init__(self, other):
        self.other = other

    def Get_rank(self):
        return 0

    def Get_size(self):
        return 2

    def Split_type(self, kind):
        return self

    def allgather(self, mine):
        return [mine, self.other(mine)]


MPI_CONSTANTS = type("MPI", (), {"COMM_TYPE_SHARED": 0})


def test_processes_whose_models_differ_stop_with_one_line():
    """MPIGroup.check_same on a world whose processes hash their models differently: a DeviceError naming the first
    process that differs (the command line prints it as one line, exit 2); equal hashes pass."""
    from dc4gs_cl.errors import DeviceError
    from dc4gs_cl.train.parallel import MPIGroup
    model = {"means": np.zeros((3, 3), np.float32)}
    MPIGroup(TwoProcessWorld(lambda mine: mine), MPI_CONSTANTS).check_same(model, "iteration 30")
    with pytest.raises(DeviceError, match="iteration 30: the model of process 1 differs from process 0's"):
        MPIGroup(TwoProcessWorld(lambda mine: "0" * 64), MPI_CONSTANTS).check_same(model, "iteration 30")


def test_processes_started_with_other_settings_stop_with_one_line_naming_the_first():
    """MPIGroup.check_same_settings on a world whose process 1 has other settings: an InputError naming the first
    one that differs by its flag (in process 0's order), before anything is sized by them."""
    from dc4gs_cl.train.parallel import MPIGroup
    settings, names = {"strategy": "3dgs", "sh_degree": 3, "out": "/a"}, {"strategy": "--strategy", "out": "--out"}

    def group(**other):
        return MPIGroup(TwoProcessWorld(lambda mine: {**mine, **other}), MPI_CONSTANTS)
    group().check_same_settings(settings, names)
    with pytest.raises(InputError, match=r"^process 1 was started with --strategy 'absgs', process 0 with '3dgs'"):
        group(out="/b", strategy="absgs").check_same_settings(settings, names)
    with pytest.raises(InputError, match=r"^process 1 was started with --out '/b', process 0 with '/a'"):
        group(out="/b").check_same_settings(settings, names)


@needs_mpi
@pytest.mark.parametrize("other, named", [(["--strategy", "absgs"], "--strategy"),
                                          (["--sh-degree", "1"], "--sh-degree"), (["--dc4gs"], "--dcc"),
                                          (["--seed", "3"], "--seed")])
def test_ranks_started_with_other_settings_all_stop_before_training(tmp_path, other, named):
    """mpirun's `-n 1 dc4gs-cl train ... : -n 1 dc4gs-cl train ... --strategy absgs` corrupted the heap (SIGABRT),
    --sh-degree the same, --dc4gs on one rank hung, --seed was caught only at the end."""
    train = [sys.executable, "-m", "dc4gs_cl", "train", "--no-progress", "--lpips", "none", *RUN, "--out",
             str(tmp_path / "run")]
    cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "-n", "1", *train, ":", "-n", "1", *train, *other]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert f"process 1 was started with {named} " in done.stderr, done.stderr[-2000:]
    assert "free()" not in done.stderr and not (tmp_path / "run" / "config.json").exists()


def test_the_window_columns_that_take_a_maximum_exist():
    """statistics.MAX_COLUMNS names window columns (a renamed column would be summed silently)."""
    columns = {f.name for f in StatisticsSpec(dc=True, split_candidates=5).window.fields}
    assert set(MAX_COLUMNS) <= columns
