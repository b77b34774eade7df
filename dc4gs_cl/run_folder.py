"""A training run's folder, in the Inria layout, and everything read from or written to it: paths, the
run's settings, checkpoints, saved models and evaluation results. Train, eval, render and the tools all
go through this module; every file is written atomically (files.py).

    config.json                           the run's settings (TrainConfig), read back by --resume and eval
    cfg_args, cameras.json                the settings and cameras as the Inria tools read them
    checkpoint.npz                        the whole training state (arrays and a JSON "meta" entry holding
                                          the arrays' SHA-256)
    checkpoint.prev.npz                   the checkpoint before it, kept until the new one is complete, and
                                          resumed from when checkpoint.npz is corrupt
    point_cloud/iteration_N/point_cloud.ply   the model saved at iteration N (standard 3DGS PLY)
    results.json, per_view.json           test-view metrics keyed by "ours_N"
    exposure.json                         train --exposure: each training photo's colour correction at the last
                                          checkpoint (for inspection; the checkpoint holds them for --resume)
    metrics.jsonl                         the run's metrics over iterations, a JSON object per line, appended
                                          while training (train/log.py); `dc4gs-cl report` draws them
    <split>/ours_N/{renders,gt}/          rendered views beside their ground truth
    path-KIND/ours_N/                     the frames of a camera path (render --path) and their video beside them
    undistorted/                          the scene's undistorted images, cached

`render --out` writes the same layout without the iterations (OUT/<split>/renders/, OUT/path-KIND/) and caches its
scene's images there too.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import TrainConfig
from .errors import InputError, OutputError
from .files import exclusive_lock, is_temporary, write_atomic, write_json
from .model import GaussianModel
from .ply import read_ply, write_ply
from .scene.camera import Scene

CONFIG = "config.json"
CHECKPOINT, PREVIOUS_CHECKPOINT = "checkpoint.npz", "checkpoint.prev.npz"
CORRUPT_CHECKPOINT = "checkpoint.corrupt.npz"   # a checkpoint found corrupt, set aside when resuming past it
LOCK = ".lock"   # held by the run writing the folder (RunFolder.locked), the holder's PID inside
RESULTS, PER_VIEW = "results.json", "per_view.json"
ITERATION_KEY = "ours_"   # + N: the results' key and the views' folder of the model at iteration N (the Inria code's)
RENDERS, GROUND_TRUTH = "renders", "gt"   # a views folder's renders and the images they are compared with
UNDISTORTED = "undistorted"   # the scene's undistorted images, cached
METRICS = "metrics.jsonl"
EXPOSURE = "exposure.json"
# The numbers a metrics row may hold (train/log.py writes them; report plots them), and stage_ms: stage -> ms
METRIC_NUMBERS = ("loss", "train_psnr", "gaussians", "it_per_s", "elapsed_s", "test_psnr", "test_ssim", "test_lpips",
                  "test_lpips_alex", "test_views", "test_psnr_corrected", "test_ssim_corrected")
RUN_FILES = (CONFIG, "cfg_args", "cameras.json", CHECKPOINT, PREVIOUS_CHECKPOINT, CORRUPT_CHECKPOINT, RESULTS, PER_VIEW,
             METRICS, EXPOSURE, "results.corrupt.json", "per_view.corrupt.json")
MODELS, MODEL_KEY = "point_cloud", "iteration_"   # + N: the folder of the model saved at iteration N
RUN_DIRS = (MODELS, "test", "train")
META = "meta"           # the checkpoint entry holding the JSON metadata
CHECKSUM = "sha256"     # the metadata key holding checkpoint_checksum(arrays, meta)
# TrainingState's array groups, "<group>/<name>", in its fields' order
STATE_GROUPS = ("param", "m", "v", "window", "exposure")


def checkpoint_checksum(arrays: dict[str, np.ndarray], meta: dict) -> str:
    """SHA-256 over the metadata (but its checksum) and every array's name, dtype, shape and bytes."""
    h = hashlib.sha256(json.dumps({k: v for k, v in meta.items() if k != CHECKSUM}, sort_keys=True).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _read_checkpoint_file(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    try:
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
        meta = json.loads(bytes(arrays.pop(META)).decode())
        if not isinstance(meta, dict):
            raise ValueError("metadata is not a JSON object")
    except Exception as e:   # zipfile, zlib and numpy raise a dozen kinds on a damaged archive; all mean "corrupt"
        raise InputError(path, f"corrupt checkpoint ({e.__class__.__name__}: {_one_line(e)})") from None
    # checkpoints before checksums have none
    if CHECKSUM in meta and meta[CHECKSUM] != checkpoint_checksum(arrays, meta):
        raise InputError(path, "corrupt checkpoint (checksum mismatch)")
    return arrays, meta


def _one_line(e: Exception | str) -> str:
    return " ".join(str(e).split())


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:   # NaN included: a rate over no time is written as NaN
    return _is_int(value) or isinstance(value, float)


@dataclass
class TrainingState:
    """What a checkpoint holds: all a run needs to continue bit for bit. The arrays are stored in STATE_GROUPS,
    the rest in the JSON metadata, with the Gaussian count."""
    config: TrainConfig
    params: dict[str, np.ndarray]   # the Gaussians' parameters (name -> (n, width)) ...
    m: dict[str, np.ndarray]        # ... and Adam's moments, same names and shapes
    v: dict[str, np.ndarray]
    window: dict[str, np.ndarray]   # the densification window's columns
    iteration: int
    adam_steps: int
    rng: dict                       # the NumPy bit generator's state
    camera_stack: list[int]
    train_cameras: list[str]        # their names: a run resumed with other images is refused
    loss_sums: tuple[list[float], int] | None   # the loss's running sums and calls (None before metrics.jsonl)
    exposure: dict[str, np.ndarray] | None = None   # --exposure: the corrections "T" and their moments "m", "v"

    def entries(self) -> tuple[dict[str, np.ndarray], dict]:
        """The named arrays and metadata that RunFolder.write_checkpoint writes."""
        groups = dict(zip(STATE_GROUPS, (self.params, self.m, self.v, self.window, self.exposure or {})))
        arrays = {f"{group}/{k}": a for group, named in groups.items() for k, a in named.items()}
        meta = {"iteration": self.iteration, "config": self.config.to_json(), "adam_steps": self.adam_steps,
                "rng": self.rng, "camera_stack": self.camera_stack, "train_cameras": self.train_cameras,
                "gaussians": len(self.params["means"]), "loss_sums": self.loss_sums}
        return arrays, meta


@dataclass
class Checkpoint:
    path: Path                      # the file read
    arrays: dict[str, np.ndarray]
    meta: dict
    passed_over: list[InputError]   # newer checkpoints found corrupt

    def training_state(self, loss_stats: int) -> TrainingState:
        """The state the arrays and metadata hold (TrainingState.entries wrote them); InputError where they hold
        none. loss_stats: how many running sums the loss keeps (loss.STAT_KEYS)."""
        meta = self.meta
        named = lambda group: {k.split("/", 1)[1]: a for k, a in self.arrays.items() if k.startswith(group + "/")}
        params, m, v, window, exposure = map(named, STATE_GROUPS)
        try:
            loss_sums = meta.get("loss_sums")
            if loss_sums is not None:   # checkpoints before metrics.jsonl have none
                sums, calls = loss_sums
                loss_sums = [float(x) for x in sums], int(calls)
                if len(sums) != loss_stats:
                    raise ValueError(f"loss_sums holds {len(sums)} sums")
            state = TrainingState(TrainConfig.from_json(meta["config"]), params, m, v, window, meta["iteration"],
                                  meta["adam_steps"], meta["rng"], meta["camera_stack"], meta["train_cameras"],
                                  loss_sums, exposure or None)
            n = meta["gaussians"]
        except (KeyError, TypeError, ValueError, InputError) as e:
            raise InputError(self.path, f"corrupt checkpoint ({e.__class__.__name__}: {e})") from None
        if any(a.shape[:1] != (n,) for named in (params, m, v) for a in named.values()):
            raise InputError(self.path, f"corrupt checkpoint (arrays of other lengths than its {n} Gaussians)")
        return state


class RunFolder:
    def __init__(self, path: str | Path):
        self.path = Path(path)

    def __str__(self) -> str:
        return str(self.path)

    # paths ---------------------------------------------------------------------------------------------
    @property
    def config_path(self) -> Path:
        return self.path / CONFIG

    @property
    def checkpoint_path(self) -> Path:
        return self.path / CHECKPOINT

    @property
    def checkpoint_paths(self) -> tuple[Path, Path]:
        """The newest checkpoint and the one before it, in the order --resume tries them."""
        return self.path / CHECKPOINT, self.path / PREVIOUS_CHECKPOINT

    def has_checkpoint(self) -> bool:
        return any(p.is_file() for p in self.checkpoint_paths)

    def model_path(self, iteration: int) -> Path:
        return self.path / MODELS / f"{MODEL_KEY}{iteration}" / "point_cloud.ply"

    def views_dir(self, split: str, iteration: int) -> Path:
        """Where a split's renders/ and gt/ of the model at `iteration` go."""
        return self.path / split / f"{ITERATION_KEY}{iteration}"

    def rendered_iterations(self, split: str) -> list[int]:
        """The iterations whose views of a split were rendered (views_dir), in order."""
        return sorted(int(m.group(1)) for d in (self.path / split).glob(f"{ITERATION_KEY}*")
                      if (m := re.fullmatch(rf"{ITERATION_KEY}(\d+)", d.name)) and d.is_dir())

    def path_frames_dir(self, kind: str, iteration: int | None = None) -> Path:
        """Where render --path writes the frames of a camera path of this KIND: path-KIND/ours_N/ for the model at
        `iteration`; path-KIND/ in render's --out (no iteration)."""
        frames = self.path / f"path-{kind}"
        return frames if iteration is None else frames / f"{ITERATION_KEY}{iteration}"

    @property
    def images_cache(self) -> Path:
        """Where the scene's undistorted images are cached."""
        return self.path / UNDISTORTED

    # the folder as a whole -------------------------------------------------------------------------------
    def holds_run(self) -> bool:
        return bool(self.run_files())

    def run_files(self) -> list[str]:
        """The names of a run's files and folders this folder holds (folders with a trailing /)."""
        return [f for f in RUN_FILES if (self.path / f).exists()] + [f"{d}/" for d in RUN_DIRS
                                                                     if (self.path / d).exists()]

    def missing_for_resume(self) -> str | None:
        """What --resume would lack here: config.json or checkpoint.npz (None: the run can be resumed)."""
        return CONFIG if not self.config_path.is_file() else None if self.has_checkpoint() else CHECKPOINT

    def clear(self) -> None:
        """Remove a previous run's files, only ours: its RUN_FILES, and in its RUN_DIRS only the folders a run
        writes (point_cloud/iteration_N/, <split>/ours_N/), each RUN_DIR then removed if nothing else is left in it.
        Anything else stays (--force once deleted a NeRF scene's train/ and test/ photos). A RUN_DIR that is a
        symbolic link is removed itself, never followed (renders were written through one)."""
        for f in RUN_FILES:
            (self.path / f).unlink(missing_ok=True)
        for d in RUN_DIRS:
            folder = self.path / d
            if folder.is_symlink():
                folder.unlink()
                continue
            ours = rf"{MODEL_KEY if d == MODELS else ITERATION_KEY}\d+"
            for sub in folder.glob("*") if folder.is_dir() else ():
                if re.fullmatch(ours, sub.name) and sub.is_dir() and not sub.is_symlink():
                    shutil.rmtree(sub, ignore_errors=True)
            with contextlib.suppress(OSError):   # not empty: what is left is not ours
                folder.rmdir()

    @contextlib.contextmanager
    def locked(self):
        """Hold the folder for one run (an exclusive flock on its LOCK file, which names the holder's PID): a second
        run into it is an InputError naming that PID. The OS lets go when the process ends, however it ends. A
        folder made here is removed again if the run ends before writing its settings (refused, failed or stopped
        while its scene loads: the undistorted images it cached so far go with it)."""
        made = not self.path.exists()
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OutputError(self.path, f"cannot be made ({e.strerror})") from e
        try:
            with exclusive_lock(self.path / LOCK, lambda holder: InputError(
                    self.path, f"is in use by another run (PID {holder}): wait for it to end, or train into another "
                               "--out")):
                yield self
        finally:
            if made and not (self.path / CONFIG).exists():
                shutil.rmtree(self.path, ignore_errors=True)

    def remove_temporaries(self) -> list[Path]:
        """Remove the temporary files an interrupted write left (files.temporary_sibling's names: a process killed
        inside a checkpoint or model write), in the folder and its run folders; the ones removed."""
        folders = [self.path, *(p for d in RUN_DIRS for p in (self.path / d).rglob("*") if p.is_dir())]
        stale = [p for folder in folders for p in folder.glob(".*") if p.is_file() and is_temporary(p)]
        for p in stale:
            p.unlink(missing_ok=True)
        return stale

    # settings --------------------------------------------------------------------------------------------
    def write_settings(self, cfg: TrainConfig, scene) -> None:
        """config.json, and for the Inria tools cfg_args and cameras.json (scene: scene.camera.Scene)."""
        write_json(self.config_path, cfg.to_json())
        # the Inria code's Namespace, with what is true of this run only: no source_path for the built-in scene
        # (it has no folder), images only where that folder is the scene's, no data_device (there is no CUDA)
        root = Path(scene.root)
        values = {"sh_degree": cfg.sh_degree, **({"source_path": str(root.resolve())} if root.exists() else {}),
                  "model_path": str(self.path.resolve()),
                  **({"images": "images"} if (root / "images").is_dir() else {}), "resolution": cfg.resolution or -1,
                  "white_background": cfg.white_background, "eval": cfg.test_every > 0}
        cfg_args = "Namespace(" + ", ".join(f"{k}={v!r}" for k, v in values.items()) + ")"
        write_atomic(self.path / "cfg_args", lambda tmp: tmp.write_text(cfg_args))
        cams = [{"id": i, "img_name": Path(c.name).stem, "width": c.width, "height": c.height,
                 "position": c.center.tolist(), "rotation": c.R.T.tolist(), "fy": c.fy, "fx": c.fx}
                for i, c in enumerate(scene.train + scene.test)]
        write_json(self.path / "cameras.json", cams)

    def read_config(self) -> TrainConfig:
        if not self.config_path.is_file():
            raise InputError(self.path, "not a training output folder (no config.json)")
        try:
            return TrainConfig.from_json(json.loads(self.config_path.read_text(encoding="utf-8")))
        except (OSError, ValueError, TypeError, InputError) as e:   # ValueError covers bad JSON and bad UTF-8
            problem = e.problem if isinstance(e, InputError) else _one_line(e)
            raise InputError(self.config_path, f"unreadable run settings ({problem})") from None

    def check_not_the_scene(self, scene: Scene) -> None:
        """InputError where this folder is, holds, or lies inside the folder of the scene's images: a run's
        --force would clear it (a NeRF scene's train/ and test/ were deleted that way) and its renders mix in."""
        out = self.path.resolve()
        for folder in sorted({c.image_path.parent.resolve() for c in scene.train + scene.test if c.image_path}):
            if folder == out or out in folder.parents or folder in out.parents:
                raise InputError(self.path, f"is, holds or lies inside the scene's image folder {folder}: write the "
                                            "run elsewhere (--out)")

    def load_scene(self, cfg: TrainConfig | None = None, scene: str | None = None, resolution: int | None = None,
                   white_background: bool = False) -> Scene:
        """The scene as the run's settings load it (cfg, else config.json): its resolution, test views,
        background and alpha masks, the undistorted images cached in the folder. scene and resolution replace
        the run's, white_background makes it white (render's --scene, -r, --white-background)."""
        from .scene.loader import load_scene   # pycolmap and OpenImageIO: only where a scene is read
        cfg = self.read_config() if cfg is None else cfg
        return load_scene(scene or cfg.scene, resolution=resolution or cfg.resolution,
                          cache_dir=self.images_cache, test_every=cfg.test_every,
                          test_split=cfg.test_split, white_background=white_background or cfg.white_background,
                          alpha_mask=cfg.alpha_mask, undistort=cfg.undistort)

    # models ----------------------------------------------------------------------------------------------
    def save_model(self, iteration: int, model: GaussianModel) -> Path:
        path = self.model_path(iteration)
        write_ply(path, model)
        return path

    def saved_iterations(self) -> list[int]:
        return sorted(int(m.group(1)) for d in (self.path / MODELS).glob(f"{MODEL_KEY}*")
                      if (m := re.fullmatch(rf"{MODEL_KEY}(\d+)", d.name)) and (d / "point_cloud.ply").is_file())

    def load_model(self, iteration: int | None = None) -> tuple[int, GaussianModel]:
        """The model saved at `iteration` (None: the last one) and that iteration."""
        saved = self.saved_iterations()
        if not saved:
            raise InputError(self.path / "point_cloud", "no saved model (point_cloud/iteration_N/point_cloud.ply)")
        iteration = saved[-1] if iteration is None else iteration
        if iteration not in saved:
            raise InputError(self.path / "point_cloud", f"no model saved at iteration {iteration} (saved: {saved})")
        return iteration, read_ply(self.model_path(iteration))

    # checkpoints -----------------------------------------------------------------------------------------
    def write_checkpoint(self, arrays: dict[str, np.ndarray], meta: dict) -> None:
        """The training state: named arrays and JSON metadata (with the arrays' checksum). The new file is
        written whole under a temporary name first; only then does the current checkpoint become
        checkpoint.prev.npz and the new one take its place, so a complete checkpoint exists at every moment
        (a failed write, e.g. a full disk, leaves both earlier ones untouched)."""
        meta = {**meta, CHECKSUM: checkpoint_checksum(arrays, meta)}
        entries = {**arrays, META: np.frombuffer(json.dumps(meta).encode(), np.uint8)}

        def write(tmp):
            with open(tmp, "wb") as f:
                np.savez(f, **entries)
                f.flush()
                os.fsync(f.fileno())
        current, previous = self.checkpoint_paths
        write_atomic(current, write, keep_previous=previous)

    def read_checkpoint(self) -> Checkpoint:
        """The newest intact checkpoint; a corrupt one is passed over (and named in `passed_over`) for the one
        before it, and set aside as CORRUPT_CHECKPOINT, so that the next checkpoint written does not make it the
        previous one. Raises InputError when there is none, or none intact."""
        existing = [p for p in self.checkpoint_paths if p.is_file()]
        if not existing:
            raise InputError(self.path, f"nothing to resume: no {CHECKPOINT}")
        passed_over = []
        for path in existing:
            try:
                arrays, meta = _read_checkpoint_file(path)
            except InputError as e:
                passed_over.append(e)
                continue
            if passed_over:
                os.replace(existing[0], self.path / CORRUPT_CHECKPOINT)
            return Checkpoint(path, arrays, meta, passed_over)
        raise InputError(existing[0], "; ".join(e.problem if e.path == str(existing[0]) else str(e)
                                                for e in passed_over) + "; no intact checkpoint left to resume from")

    # metrics over iterations -----------------------------------------------------------------------------
    @property
    def metrics_path(self) -> Path:
        return self.path / METRICS

    def read_metrics(self) -> list[dict]:
        """The metrics rows in the order written. Appending is not atomic: a last line cut short by a crash is
        left out, as is any line that is not a JSON object with an integer "iteration". A row whose numbers are
        not numbers (METRIC_NUMBERS, stage_ms) is an InputError naming its line: what reads the rows may compute
        with them."""
        try:
            lines = self.metrics_path.read_text(encoding="utf-8").splitlines()
        except FileNotFoundError:
            return []
        except (OSError, UnicodeDecodeError) as e:
            raise InputError(self.metrics_path, f"unreadable metrics ({_one_line(e)})") from None
        rows = []
        for number, line in enumerate(lines, 1):
            try:
                row = json.loads(line)
            except ValueError:
                continue
            if isinstance(row, dict) and _is_int(row.get("iteration")):
                wrong = [(k, row[k]) for k in METRIC_NUMBERS if k in row and not _is_number(row[k])]
                stages = row.get("stage_ms", {})
                if not isinstance(stages, dict) or not all(_is_number(v) for v in stages.values()):
                    wrong.append(("stage_ms", stages))
                if wrong:
                    key, value = wrong[0]
                    raise InputError(self.metrics_path, f"line {number}: {key} is {_one_line(repr(value))[:60]}, "
                                                        "not a number")
                rows.append(row)
        return rows

    def append_metrics(self, row: dict) -> None:
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            with open(self.metrics_path, "a", encoding="utf-8") as f:
                f.write(json.dumps(row) + "\n")
        except OSError as e:
            raise OutputError(self.metrics_path, f"cannot write: {e.strerror or e}") from e

    def cut_metrics(self, iteration: int) -> list[dict]:
        """Keep the rows up to `iteration` (where a resumed run continues; later rows came from the part of the
        interrupted run that is trained again), rewriting the file atomically; returns the rows kept."""
        kept = [r for r in self.read_metrics() if r["iteration"] <= iteration]
        if self.metrics_path.exists():
            write_atomic(self.metrics_path, lambda tmp: tmp.write_text("".join(json.dumps(r) + "\n" for r in kept)))
        return kept

    # exposure --------------------------------------------------------------------------------------------
    @property
    def exposure_path(self) -> Path:
        return self.path / EXPOSURE

    def write_exposure(self, iteration: int, photos: list[str], corrections: np.ndarray) -> None:
        """exposure.json: each training photo's correction [photos][12] as its 3 x 4 rows [A_i0, A_i1, A_i2, b_i]
        (corrected = A rgb + b), at `iteration`."""
        write_json(self.exposure_path, {
            "iteration": iteration, "layout": "corrected rgb = A rgb + b; each row [A_i0, A_i1, A_i2, b_i]",
            "photos": {name: np.asarray(t, np.float64).reshape(3, 4).tolist() for name, t in zip(photos, corrections)}})

    def read_exposure(self) -> dict[str, np.ndarray]:
        """exposure.json's corrections: photo name -> its 3 x 4 [A | b]."""
        data = json.loads(self.exposure_path.read_text(encoding="utf-8"))
        return {name: np.asarray(rows, np.float64) for name, rows in data["photos"].items()}

    # results ---------------------------------------------------------------------------------------------
    @property
    def results_path(self) -> Path:
        return self.path / RESULTS

    def read_results(self, iteration: int, per_view: bool = False) -> dict:
        """The evaluation of the model at `iteration` that write_results stored: its means (results.json), or with
        per_view its metrics per view (per_view.json). OSError, ValueError or KeyError where there is none."""
        return json.loads((self.path / (PER_VIEW if per_view else RESULTS)).read_text())[f"{ITERATION_KEY}{iteration}"]

    def write_results(self, iteration: int, result: dict) -> list[str]:
        """Merge an evaluation (evaluate.evaluate) into results.json and per_view.json under "ours_N"; other
        iterations' entries are kept. A file that is not a JSON object (damaged, edited) is set aside as
        <name>.corrupt.json and started afresh, so that the evaluation's work is not lost: what was set aside
        is returned, a line each, for the command to say."""
        key, set_aside = f"{ITERATION_KEY}{iteration}", []
        for name, value in ((RESULTS, result["mean"]), (PER_VIEW, result["per_view"])):
            path = self.path / name
            try:
                data = json.loads(path.read_text()) if path.exists() else {}
            except (OSError, ValueError) as e:
                data = e
            if not isinstance(data, dict):
                why = _one_line(data) if isinstance(data, Exception) else f"a JSON {type(data).__name__}, not an object"
                aside = path.with_suffix(".corrupt.json")
                os.replace(path, aside)
                set_aside.append(f"{path}: not a results file ({why}); set aside as {aside.name}")
                data = {}
            data[key] = value
            write_json(path, data)
        return set_aside
