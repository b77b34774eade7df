"""Work shapes the device tests run in; random inputs come from dc4gs_cl.reference.testing; the tools' modules."""
from __future__ import annotations

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

from dc4gs_cl.render import Tuning
from dc4gs_cl.render.tuning import DEAL_TILES_CPU
from dc4gs_cl.runtime import Capabilities
from dc4gs_cl.reference.testing import distorted_camera, random_camera, random_model  # noqa: F401 (re-exported)

# Both work shapes of every kernel run on PoCL: the CPU's (256 pixels per work-item) and the GPUs'
# (1 pixel per work-item, cooperative work-groups, work-groups ranking 8-bit sort digits), plus one in between.
CPU_SHAPE = Tuning(pixels_per_item=256, batch=64, radix_bits=8, sort_blocks=8, scan_wg=1, scan_groups=8, isect_wg=64,
                   deal_tiles=DEAL_TILES_CPU)
GPU_SHAPE = Tuning(pixels_per_item=1, batch=256, radix_bits=8, sort_blocks=512, sort_wg=256, scan_wg=256,
                   scan_groups=64, isect_wg=256)
# small sort work-groups: 6-bit digits ranked 4 + 2 bits at a time, more digits than items
MID_SHAPE = replace(CPU_SHAPE, pixels_per_item=16, batch=16, radix_bits=6, sort_blocks=37, sort_wg=16, scan_wg=16,
                    scan_groups=5)
SHAPES = {"cpu": CPU_SHAPE, "gpu": GPU_SHAPE, "mid": MID_SHAPE}
# The GPU shape on a device whose work-groups hold at most 64 items (Tuning.within): 4 pixels per item.
NARROW_CAPS = Capabilities(is_cpu=False, compute_units=1, max_work_group_size=64, local_mem_size=32 * 1024,
                           float_atomic_add=False, fp64=False)
NARROW_SHAPE = GPU_SHAPE.within(NARROW_CAPS)


def load_tool(name: str):
    """A module of tools/ (not a package), e.g. load_tool("fuzz_inputs")."""
    path = Path(__file__).resolve().parents[1] / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module      # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module

def straight_and_resumed(cfg, scene, rt, folder: Path, stop_at: int) -> tuple:
    """Two trainers of cfg: one trained straight to cfg.iterations, one stopped after stop_at (a checkpoint
    written), made anew and resumed from it to the end (what an interrupted run does)."""
    from dc4gs_cl.train import Trainer

    def run(out, upto, resume=False):
        trainer = Trainer(cfg, scene, rt, out)
        if resume:
            trainer.resume()
        while trainer.iteration < upto:
            trainer.step()
        return trainer
    straight = run(folder / "straight", cfg.iterations)
    run(folder / "stopped", stop_at).save_checkpoint()
    return straight, run(folder / "stopped", cfg.iterations, resume=True)
