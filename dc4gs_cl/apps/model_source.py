"""What render, view and export read a model from: a training run's folder (the model saved at an iteration, and
the settings the run trained with) or a model file of any format `export` writes."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..config import TrainConfig
from ..model import GaussianModel
from ..run_folder import RunFolder
from .export import read_model_file, recorded_antialiased


@dataclass(frozen=True)
class ModelSource:
    model: GaussianModel
    run: RunFolder | None = None      # the run folder it was saved in (None: a model file)
    cfg: TrainConfig | None = None    # that run's settings (None also for a folder without them, which export takes)
    iteration: int | None = None      # the iteration it was saved at
    recorded: bool | None = None      # the rasterization mode a model file records (.spz; None: the others)

    @staticmethod
    def of_run(path: str | os.PathLike, iteration: int | None = None, settings_optional: bool = False) -> ModelSource:
        """A run folder's model saved at `iteration` (None: the last) and the run's settings: InputError where there
        is no such model, or no settings (config.json) unless they are optional."""
        run = RunFolder(path)
        cfg = run.read_config() if not settings_optional or run.config_path.is_file() else None
        iteration, model = run.load_model(iteration)
        return ModelSource(model, run, cfg, iteration)

    @staticmethod
    def of_file(path: str | os.PathLike) -> ModelSource:
        return ModelSource(read_model_file(path), recorded=recorded_antialiased(path))

    @staticmethod
    def of_path(path: str | os.PathLike, iteration: int | None = None) -> ModelSource:
        """A run folder's model (of_run) or a model file's, whichever the path is."""
        return ModelSource.of_run(path, iteration) if Path(path).is_dir() else ModelSource.of_file(path)

    @property
    def antialiased(self) -> bool | None:
        """Whether the model trained antialiased, as far as it says: its run's setting, else its file's record."""
        return self.cfg.antialiased if self.cfg is not None else self.recorded
