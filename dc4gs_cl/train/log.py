"""What a training run reports while it runs: the progress display (a bar on a terminal, else one line every
N iterations, as a log file or a job scheduler wants) and the metrics file that `dc4gs-cl report` draws.

The metrics file (run_folder.METRICS) holds one JSON object per line, appended as training goes so that a
report can be drawn during the run:
    {"iteration": 120, "loss": 0.051, "train_psnr": 24.3, "gaussians": 5210, "it_per_s": 17.9,
     "elapsed_s": 6.7, "stage_ms": {"project": 0.4, ...}}        a sample, every SAMPLE_EVERY iterations
    {"iteration": 1400, "test_psnr": 27.9, "test_ssim": 0.91, "test_lpips": 0.12, "test_views": 3}
                                                    an evaluation (test_lpips: VGG's LPIPS, where it was computed;
                                                    test_lpips_alex: AlexNet's)
train_psnr is the last training view's; it_per_s is over the samples' interval; elapsed_s counts training
only (evaluations excluded) and continues across --resume; stage_ms (device time per iteration over the
interval, by stage) is there when the run profiles (train --profile).
"""
from __future__ import annotations

import math
import sys
import time
from typing import Callable

from ..config import DEFAULT_LINE_EVERY
from ..run_folder import RunFolder

SAMPLE_EVERY = 10           # iterations between samples (the loss is read back this often anyway)
PROGRESS_MODES = ("bar", "lines", "none")


def progress_mode(no_progress: bool) -> str:
    """No display when asked; a redrawn bar on a terminal; otherwise one line per interval (a bar written to a
    file is hundreds of carriage-return redraws)."""
    if no_progress:
        return "none"
    return "bar" if sys.stderr.isatty() else "lines"


class TrainingLog:
    def __init__(self, run_folder: RunFolder | None, total: int, iteration: int, mode: str = "bar",
                 line_every: int = DEFAULT_LINE_EVERY, stage_times: Callable[[], dict[str, float]] | None = None):
        """iteration: where training starts (a resumed run: its checkpoint's), the metrics file is cut back to
        it (run_folder None: no metrics file, a parallel run's other processes). stage_times: the runtime's per-stage
        device seconds since its last call (profiling runs only)."""
        if mode not in PROGRESS_MODES:
            raise ValueError(f"progress mode {mode!r} is not one of {PROGRESS_MODES}")
        self.run_folder, self.total, self.mode, self.line_every = run_folder, total, mode, line_every
        self.stage_times, self.stream = stage_times, sys.stderr
        earlier = run_folder.cut_metrics(iteration) if run_folder is not None else []
        self.elapsed = next((r["elapsed_s"] for r in reversed(earlier) if "elapsed_s" in r), 0.0)
        self.last_iteration, self.last_time = iteration, time.perf_counter()
        self.paused_at: float | None = None
        self.stage_seconds: dict[str, float] = {}   # this session's device time by stage (train --profile)
        self.profiled_iterations = 0
        self.bar = None
        if mode == "bar":
            from tqdm import tqdm
            self.bar = tqdm(total=total, initial=iteration, dynamic_ncols=True, unit="it", file=self.stream)

    def step(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def sample(self, iteration: int, loss: float, mse: float, gaussians: int) -> dict:
        """Record the training state after `iteration`; returns the row written."""
        now = time.perf_counter()
        seconds = now - self.last_time
        self.elapsed += seconds
        done = iteration - self.last_iteration
        psnr = 10 * math.log10(1 / max(mse, 1e-12))
        row = {"iteration": iteration, "loss": round(loss, 6), "train_psnr": round(psnr, 4), "gaussians": gaussians,
               "it_per_s": round(done / seconds, 3) if seconds > 0 else math.nan, "elapsed_s": round(self.elapsed, 3)}
        if self.stage_times is not None and done > 0:
            times = self.stage_times()
            row["stage_ms"] = {k: round(v / done * 1e3, 4) for k, v in times.items()}
            for k, v in times.items():
                self.stage_seconds[k] = self.stage_seconds.get(k, 0.0) + v
            self.profiled_iterations += done
        if self.run_folder is not None:
            self.run_folder.append_metrics(row)
        self.last_iteration, self.last_time = iteration, now
        if self.bar is not None:
            self.bar.set_postfix(loss=f"{loss:.4f}", psnr=f"{row['train_psnr']:.2f}", gaussians=f"{gaussians:,}",
                                 refresh=False)
        elif self.mode == "lines" and (iteration % self.line_every == 0 or iteration == self.total):
            left = (self.total - iteration) / row["it_per_s"] if row["it_per_s"] > 0 else math.nan
            print(f"iteration {iteration:,}/{self.total:,}  loss {loss:.4f}  train PSNR {row['train_psnr']:.2f} dB  "
                  f"{gaussians:,} Gaussians  {row['it_per_s']:.1f} it/s  {self.elapsed:.0f} s, about {left:.0f} s left",
                  file=self.stream, flush=True)
        return row

    def pause(self) -> None:
        """Stop the training clock (an evaluation is not training time)."""
        self.paused_at = time.perf_counter()

    def resume(self) -> None:
        if self.paused_at is not None:
            self.last_time += time.perf_counter() - self.paused_at
            self.paused_at = None

    def evaluation(self, iteration: int, result: dict) -> dict:
        """Record a test-view evaluation (evaluate.evaluate's result) at `iteration`."""
        from ..evaluation.evaluate import CORRECTED, summary
        row = {"iteration": iteration, "test_psnr": round(result["mean"]["PSNR"], 4),
               "test_ssim": round(result["mean"]["SSIM"], 5),
               "test_views": result["views"]}
        if result.get("lpips_key") in result["mean"]:   # test_lpips (VGG) or test_lpips_alex
            row[f"test_{result['lpips_key'].lower()}"] = round(result["mean"][result["lpips_key"]], 5)
        if f"PSNR{CORRECTED}" in result["mean"]:   # --corrected-metrics
            row["test_psnr_corrected"] = round(result["mean"][f"PSNR{CORRECTED}"], 4)
            row["test_ssim_corrected"] = round(result["mean"][f"SSIM{CORRECTED}"], 5)
        if self.run_folder is not None:
            self.run_folder.append_metrics(row)
        if self.mode != "none":   # unrounded, as the final line of `train` prints it
            line = f"iteration {iteration:,}: test views {summary(result)}, {result['views']} views"
            if self.bar is not None:
                self.bar.write(line, file=self.stream)
            else:
                print(line, file=self.stream, flush=True)
        return row

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
