"""Training: the recipe's schedules scaled to the run (schedule) and the loop (trainer); the run's settings
are config.TrainConfig, its folder run_folder.RunFolder."""
from .trainer import Stopped, Trainer

__all__ = ["Stopped", "Trainer"]
