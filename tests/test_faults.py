"""Faults while training: checkpoints carry a checksum and the one before them survives until the next is
complete; --resume passes over a corrupt checkpoint to the previous one; a write that fails (disk full,
read-only folder) says what failed and leaves the earlier outputs intact."""
import errno
import json
import os
import shutil

import numpy as np
import pytest

from dc4gs_cl.cli import main
from dc4gs_cl.errors import InputError
from dc4gs_cl.run_folder import CHECKPOINT, CORRUPT_CHECKPOINT, LOCK, PREVIOUS_CHECKPOINT, RunFolder

SMALL = ["--scene", "builtin", "-r", "4", "--no-progress"]


def state(rng, n=5):
    return {"param/means": rng.normal(size=(n, 3)).astype(np.float32),
            "window/count": rng.integers(0, 9, n).astype(np.float32)}


def flip_byte(path, offset):
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x40
    path.write_bytes(bytes(data))


def array_offset(path, array: np.ndarray) -> int:
    """Where an array's bytes lie in an uncompressed .npz (np.savez stores members as they are)."""
    return path.read_bytes().index(array.tobytes())


def test_the_previous_checkpoint_stays_until_the_next_is_complete(tmp_path, rng):
    run = RunFolder(tmp_path)
    first, second = state(rng), state(rng)
    run.write_checkpoint(first, {"iteration": 10})
    assert not (tmp_path / PREVIOUS_CHECKPOINT).exists()
    run.write_checkpoint(second, {"iteration": 20})
    got = run.read_checkpoint()
    assert got.path.name == CHECKPOINT and got.meta["iteration"] == 20 and not got.passed_over
    np.testing.assert_array_equal(got.arrays["param/means"], second["param/means"])
    with np.load(tmp_path / PREVIOUS_CHECKPOINT) as f:
        np.testing.assert_array_equal(f["param/means"], first["param/means"])
    assert sorted(p.name for p in tmp_path.iterdir()) == [CHECKPOINT, PREVIOUS_CHECKPOINT]   # no temporaries


@pytest.mark.parametrize("damage", ["flipped array byte", "truncated", "empty", "metadata edited"])
def test_resume_passes_over_a_corrupt_checkpoint_to_the_previous_one(tmp_path, rng, damage):
    run = RunFolder(tmp_path)
    first, second = state(rng), state(rng)
    run.write_checkpoint(first, {"iteration": 10})
    run.write_checkpoint(second, {"iteration": 20})
    current = tmp_path / CHECKPOINT
    if damage == "flipped array byte":   # the zip CRC and the checksum both see it
        flip_byte(current, array_offset(current, second["param/means"]) + int(rng.integers(60)))
    elif damage == "truncated":
        current.write_bytes(current.read_bytes()[: int(rng.integers(1, current.stat().st_size))])
    elif damage == "empty":
        current.write_bytes(b"")
    else:                                # a consistent archive whose metadata no longer matches its checksum
        with np.load(current) as f:
            entries = {k: f[k] for k in f.files}
        meta = json.loads(bytes(entries["meta"]).decode()) | {"iteration": 30}
        np.savez(current, **(entries | {"meta": np.frombuffer(json.dumps(meta).encode(), np.uint8)}))
    got = run.read_checkpoint()
    assert got.path.name == PREVIOUS_CHECKPOINT and got.meta["iteration"] == 10
    assert len(got.passed_over) == 1 and CHECKPOINT in str(got.passed_over[0])
    assert "corrupt checkpoint" in str(got.passed_over[0])
    np.testing.assert_array_equal(got.arrays["param/means"], first["param/means"])
    (tmp_path / PREVIOUS_CHECKPOINT).write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(InputError, match="no intact checkpoint left") as e:
        run.read_checkpoint()
    assert "\n" not in str(e.value)


def test_resume_from_the_command_line_says_which_checkpoint_it_continues(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", *SMALL, "--iterations", "20", "--checkpoint-every", "5", "--test-every", "0",
                 "--out", str(out)]) == 0
    final = (out / "point_cloud" / "iteration_20" / "point_cloud.ply").read_bytes()
    # as if the run had been killed after its checkpoint at iteration 15 and its last checkpoint were damaged
    shutil.rmtree(out / "point_cloud")
    flip_byte(out / CHECKPOINT, (out / CHECKPOINT).stat().st_size // 2)
    capsys.readouterr()
    assert main(["train", "--out", str(out), "--resume", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert f"{out / CHECKPOINT}: corrupt checkpoint" in err and "resuming from checkpoint.prev.npz" in err
    # the run continues from the previous checkpoint and, training being deterministic, ends where it did
    assert (out / "point_cloud" / "iteration_20" / "point_cloud.ply").read_bytes() == final


def partial_write_then_enospc(file):
    file.write(b"PK\x03\x04" + bytes(100))
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_stops_training_naming_the_file_and_keeps_the_last_checkpoint(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    real_savez, calls = np.savez, []

    def savez(file, **entries):   # the third checkpoint (iteration 15) finds the disk full
        calls.append(1)
        return partial_write_then_enospc(file) if len(calls) == 3 else real_savez(file, **entries)
    monkeypatch.setattr(np, "savez", savez)
    capsys.readouterr()
    code = main(["train", *SMALL, "--iterations", "20", "--checkpoint-every", "5", "--test-every", "0",
                 "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err[-1] == f"dc4gs-cl train: error: {out / CHECKPOINT}: cannot write: No space left on device"
    assert RunFolder(out).read_checkpoint().meta["iteration"] == 10      # the last complete one, intact
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [LOCK]   # no temporary left behind


def test_a_read_only_folder_stops_the_model_save_and_keeps_earlier_outputs(tmp_path, capsys, monkeypatch):
    """A rename refused by a read-only file system (simulated: the tests may run as root, whom chmod does not
    stop) when the final model is saved: the error names the PLY; the checkpoints stay resumable."""
    out = tmp_path / "run"
    real_replace = os.replace

    def replace(src, dst):
        if str(dst).endswith("point_cloud.ply"):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS))
        return real_replace(src, dst)
    monkeypatch.setattr(os, "replace", replace)
    capsys.readouterr()
    code = main(["train", *SMALL, "--iterations", "10", "--checkpoint-every", "5", "--test-every", "0",
                 "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    ply = out / "point_cloud" / "iteration_10" / "point_cloud.ply"
    assert code == 1 and err[-1] == f"dc4gs-cl train: error: {ply}: cannot write: Read-only file system"
    assert not ply.exists() and not list(ply.parent.iterdir())
    assert RunFolder(out).read_checkpoint().meta["iteration"] == 10


def test_a_corrupt_checkpoint_is_set_aside_so_the_next_write_keeps_the_intact_one(tmp_path, rng):
    """Resuming past a corrupt checkpoint.npz sets it aside (checkpoint.corrupt.npz): the next checkpoint written
    then keeps the intact one as checkpoint.prev.npz, where it used to move the corrupt one there."""
    run = RunFolder(tmp_path)
    first, second, third = state(rng), state(rng), state(rng)
    run.write_checkpoint(first, {"iteration": 10})
    run.write_checkpoint(second, {"iteration": 20})
    (tmp_path / CHECKPOINT).write_bytes(b"")
    assert run.read_checkpoint().meta["iteration"] == 10
    assert not (tmp_path / CHECKPOINT).exists() and (tmp_path / CORRUPT_CHECKPOINT).read_bytes() == b""
    run.write_checkpoint(third, {"iteration": 30})
    with np.load(tmp_path / PREVIOUS_CHECKPOINT) as f:
        np.testing.assert_array_equal(f["param/means"], first["param/means"])
    assert run.read_checkpoint().meta["iteration"] == 30
    run.clear()
    assert not list(tmp_path.iterdir())


def test_temporaries_of_interrupted_writes_are_removed_when_a_run_starts(tmp_path):
    """A process killed inside a checkpoint or model write leaves a hidden temporary file; the next run into the
    folder (--resume or --force) removes them, and nothing else (temporary names carry files.TEMPORARY_MARKER)."""
    out = tmp_path / "run"
    assert main(["train", *SMALL, "--iterations", "4", "--checkpoint-every", "2", "--test-every", "0",
                 "--out", str(out)]) == 0
    stale = [out / ".checkpoint.0123abcd.dc4gs-tmp.npz",
             out / "point_cloud" / "iteration_4" / ".point_cloud.89abcdef.dc4gs-tmp.ply"]
    # a user's file of the old pattern (#56: the next run removed it), and others nobody would take for ours
    kept = [out / ".mine", out / ".checkpoint.0123abcd.tmp.npz", out / ".checkpoint.notours.tmp.npz",
            out / "notes.txt"]
    for p in stale + kept:
        p.write_bytes(b"x")
    assert main(["train", *SMALL, "--iterations", "4", "--checkpoint-every", "2", "--test-every", "0",
                 "--out", str(out), "--resume"]) == 0   # a finished run: nothing left to train
    assert not any(p.exists() for p in stale) and all(p.exists() for p in kept)


def test_the_same_command_with_resume_resumes_a_dc4gs_run(tmp_path, capsys):
    """A job script re-runs its command with --resume: --dc4gs (DCC and DCS) compares as the settings it gives,
    so the run resumes (here from its last checkpoint, with nothing left to train); a real change is refused
    naming the setting."""
    command = ["train", *SMALL, "--iterations", "4", "--checkpoint-every", "2", "--test-every", "0",
               "--strategy", "absgs", "--dc4gs", "--out", str(tmp_path / "run")]
    assert main(command) == 0
    capsys.readouterr()
    assert main(command + ["--resume"]) == 0
    assert main(command + ["--resume", "--dcs-track", "0.5"]) == 2
    assert "dc4gs.track" in capsys.readouterr().err


def test_a_run_folder_holds_one_run_at_a_time(tmp_path, capsys):
    """Two runs into one --out: the second is refused in one line naming the first's PID, while the first holds the
    folder (its whole run, checks included); once the first process is gone the folder is free. A refused run
    into a new folder leaves no folder behind."""
    import subprocess
    import sys
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from dc4gs_cl.run_folder import RunFolder\n"
        f"with RunFolder({str(out)!r}).locked():\n    print('held', flush=True); time.sleep(60)")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        capsys.readouterr()
        assert main(["train", *SMALL, "--iterations", "2", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"in use by another run (PID {holder.pid})" in err
        assert main(["train", *SMALL, "--iterations", "2", "--out", str(out), "--force"]) == 2
    finally:
        holder.kill()
        holder.wait()
    assert main(["train", *SMALL, "--iterations", "2", "--test-every", "0", "--out", str(out)]) == 0
    assert main(["train", *SMALL, "--iterations", "0", "--out", str(tmp_path / "new")]) == 2
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("damage", ['{"ours_20": {"PSNR": 1', "[1, 2]"])
def test_a_damaged_results_file_is_set_aside_not_the_evaluation(tmp_path, capsys, damage):
    """results.json that is not a JSON object (cut short, edited) made eval and train fail after all their work
    with a traceback: it is set aside as results.corrupt.json, said in a line, and written afresh."""
    out = tmp_path / "run"
    assert main(["train", *SMALL, "--iterations", "3", "--out", str(out)]) == 0
    (out / "results.json").write_text(damage)
    capsys.readouterr()
    assert main(["eval", "--model", str(out), "--no-renders"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "results.json: not a results file" in err[0] and "results.corrupt.json" in err[0]
    assert (out / "results.corrupt.json").read_text() == damage
    assert list(json.loads((out / "results.json").read_text())) == ["ours_3"]
    assert "ours_3" in json.loads((out / "per_view.json").read_text())   # the intact one merged as before


@pytest.mark.parametrize("command", ["train", "render"])
def test_sigterm_while_the_scene_loads_is_a_clean_exit(tmp_path, command):
    """SIGTERM before training's own handling is in force (here while the scene loads, as during image decoding):
    exit 143 with one line and no new output folder, not pycolmap's native stack dump (its import installs glog's
    failure handler, which killed the process with a 27-frame trace)."""
    import signal
    import subprocess
    import sys
    out = tmp_path / "new"
    args = {"train": ["train", *SMALL, "--iterations", "5", "--out", str(out)],
            "render": ["render", "--scene", "builtin", "--out", str(out)]}[command]
    done = subprocess.run([sys.executable, "-c", (
        "import os, signal, sys, time\n"
        "import dc4gs_cl.scene.loader as scenes\n"
        "def loading(*a, **k):\n"
        f"    if os.path.isdir({str(out)!r}):   # train's own folder: what undistortion would have cached\n"
        f"        os.makedirs(os.path.join({str(out)!r}, 'undistorted'))\n"
        f"        open(os.path.join({str(out)!r}, 'undistorted', 'a.png'), 'wb').close()\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    time.sleep(30)\n"
        "scenes.builtin_scene = loading\n"
        "from dc4gs_cl.cli import main\n"
        f"sys.exit(main({args!r}))")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 128 + signal.SIGTERM, (done.returncode, done.stderr[-2000:])
    assert done.stderr.strip().splitlines() == [f"dc4gs-cl {command}: terminated"], done.stderr[-2000:]
    assert not out.exists()


def test_force_removes_only_what_a_run_wrote(tmp_path):
    """--force deleted any train/, test/ or point_cloud/ in --out, a NeRF scene's photos among them, and followed
    a symbolic link out of the folder: now only a run's own files and folders go, a link is removed itself."""
    out = tmp_path / "out"
    ours = [out / "config.json", out / "test" / "ours_30" / "renders" / "a.png",
            out / "point_cloud" / "iteration_30" / "point_cloud.ply", out / "train" / "ours_7" / "gt" / "b.png"]
    theirs = [out / "test" / "r_0.png", out / "test" / "ours_notes.txt", out / "point_cloud" / "mine.ply",
              out / "notes.txt"]
    for p in ours + theirs:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "ours_1").mkdir(parents=True)
    (out / "train").rename(tmp_path / "train-moved")
    (out / "train").symlink_to(elsewhere, target_is_directory=True)
    RunFolder(out).clear()
    assert not any(p.exists() for p in ours[:3]) and all(p.exists() for p in theirs)
    assert not (out / "train").exists() and (elsewhere / "ours_1").is_dir()   # the link went, not its target


def test_a_run_is_never_written_into_the_scenes_image_folder(tmp_path, capsys):
    """`train --scene s --out s --force` on a NeRF scene deleted its train/ and test/ photos: refused, named."""
    from test_scene import nerf_scene
    scene = nerf_scene(tmp_path / "s", {"camera_angle_x": 0.9},
                       [{"file_path": f"{split}/r_{i}"} for split in ("train", "test") for i in range(2)])
    photos = sorted(scene.rglob("*.png"))
    for out in (scene, scene / "train", scene / "train" / "run"):
        assert main(["train", "--scene", str(scene), "--out", str(out), "--force", "--iterations", "2"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "scene's image folder" in err[0], err
    assert sorted(scene.rglob("*.png")) == photos
