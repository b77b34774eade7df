"""A training run's folder, in the Inria layout, and everything read from or written to it: paths, the
run's settings, checkpoints, saved models and evaluation results. Train, eval, render and the tools all
go through this module; every file is written atomically (files.py).

    config.json                           the run's settings (TrainConfig), read back by --resume and eval
    cfg_args, cameras.json                the settings and cameras as the Inria tools read them
    checkpoint.npz                        the whole training state (arrays and a JSON "meta" entry)
    point_cloud/iteration_N/point_cloud.ply   the model saved at iteration N (standard 3DGS PLY)
    results.json, per_view.json           test-view metrics keyed by "ours_N"
    <split>/ours_N/{renders,gt}/          rendered views beside their ground truth
"""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np

from .errors import InputError
from .files import write_atomic, write_json
from .model import GaussianModel
from .ply import read_ply, write_ply
from .config import TrainConfig

CONFIG = "config.json"
CHECKPOINT = "checkpoint.npz"
RESULTS, PER_VIEW = "results.json", "per_view.json"
RUN_FILES = (CONFIG, "cfg_args", "cameras.json", CHECKPOINT, RESULTS, PER_VIEW)
RUN_DIRS = ("point_cloud", "test", "train")
META = "meta"   # the checkpoint entry holding the JSON metadata


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

    def model_path(self, iteration: int) -> Path:
        return self.path / "point_cloud" / f"iteration_{iteration}" / "point_cloud.ply"

    def views_dir(self, split: str, iteration: int) -> Path:
        """Where a split's renders/ and gt/ of the model at `iteration` go."""
        return self.path / split / f"ours_{iteration}"

    # the folder as a whole -------------------------------------------------------------------------------
    def holds_run(self) -> bool:
        return any((self.path / f).exists() for f in RUN_FILES + RUN_DIRS)

    def clear(self) -> None:
        """Remove a previous run's files (only ours: anything else in the folder stays)."""
        for f in RUN_FILES:
            (self.path / f).unlink(missing_ok=True)
        for d in RUN_DIRS:
            shutil.rmtree(self.path / d, ignore_errors=True)

    # settings --------------------------------------------------------------------------------------------
    def write_settings(self, cfg: TrainConfig, scene) -> None:
        """config.json, and for the Inria tools cfg_args and cameras.json (scene: scene.camera.Scene)."""
        write_json(self.config_path, cfg.to_json())
        cfg_args = (f"Namespace(sh_degree={cfg.sh_degree}, source_path={str(Path(scene.root).resolve())!r}, "
                    f"model_path={str(self.path.resolve())!r}, images='images', resolution={cfg.resolution or -1}, "
                    f"white_background={cfg.white_background}, data_device='cuda', eval={cfg.test_every > 0})")
        write_atomic(self.path / "cfg_args", lambda tmp: tmp.write_text(cfg_args))
        cams = [{"id": i, "img_name": Path(c.name).stem, "width": c.width, "height": c.height,
                 "position": c.center.tolist(), "rotation": c.R.T.tolist(), "fy": c.fy, "fx": c.fx}
                for i, c in enumerate(scene.train + scene.test)]
        write_json(self.path / "cameras.json", cams)

    def read_config(self) -> TrainConfig:
        if not self.config_path.is_file():
            raise InputError(self.path, "not a training output folder (no config.json)")
        try:
            return TrainConfig.from_json(json.loads(self.config_path.read_text()))
        except (ValueError, TypeError, AttributeError) as e:
            raise InputError(self.config_path, f"unreadable run settings ({e})") from None

    # models ----------------------------------------------------------------------------------------------
    def save_model(self, iteration: int, model: GaussianModel) -> Path:
        path = self.model_path(iteration)
        write_ply(path, model)
        return path

    def saved_iterations(self) -> list[int]:
        return sorted(int(m.group(1)) for d in (self.path / "point_cloud").glob("iteration_*")
                      if (m := re.fullmatch(r"iteration_(\d+)", d.name)) and (d / "point_cloud.ply").is_file())

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
        """The training state: named arrays and JSON metadata, replacing the previous checkpoint whole."""
        entries = {**arrays, META: np.frombuffer(json.dumps(meta).encode(), np.uint8)}

        def write(tmp):
            with open(tmp, "wb") as f:
                np.savez(f, **entries)
        write_atomic(self.checkpoint_path, write)

    def read_checkpoint(self) -> tuple[dict[str, np.ndarray], dict]:
        path = self.checkpoint_path
        if not path.is_file():
            raise InputError(self.path, f"nothing to resume: no {CHECKPOINT}")
        try:
            with np.load(path) as f:
                arrays = {k: f[k] for k in f.files}
            meta = json.loads(bytes(arrays.pop(META)).decode())
        except (OSError, ValueError, KeyError, json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(path, f"corrupt checkpoint ({e.__class__.__name__}: {e})") from None
        return arrays, meta

    # results ---------------------------------------------------------------------------------------------
    def write_results(self, iteration: int, result: dict) -> None:
        """Merge an evaluation (evaluate.evaluate) into results.json and per_view.json under "ours_N"; other
        iterations' entries are kept."""
        key = f"ours_{iteration}"
        for name, value in ((RESULTS, result["mean"]), (PER_VIEW, result["per_view"])):
            path = self.path / name
            data = json.loads(path.read_text()) if path.exists() else {}
            data[key] = value
            write_json(path, data)
