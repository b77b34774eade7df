"""Device choice: never a simulator by default, a GPU first, then the CPU implementation measured faster, with
the reason `devices` shows; runtimes installed from PyPI with a placeholder .icd are registered by path."""
import os
from dataclasses import replace
from types import SimpleNamespace

import pyopencl as cl
import pytest

from dc4gs_cl import runtime
from dc4gs_cl.cli import main
from dc4gs_cl.render import Tuning
from dc4gs_cl.runtime import choose_device, default_device, register_bundled_runtimes
from helpers import NARROW_CAPS

GPU, CPU = cl.device_type.GPU, cl.device_type.CPU
ALL = cl.device_type.ALL


def device(platform: str, kind):
    return SimpleNamespace(platform=SimpleNamespace(name=platform), type=kind, name="d", max_compute_units=2)


OCLGRIND = device("Oclgrind", ALL)               # reports every device type, GPU included
POCL = device("Portable Computing Language", CPU)
INTEL = device("Intel(R) OpenCL", CPU)
NVIDIA = device("NVIDIA CUDA", GPU)


@pytest.mark.parametrize("devices, chosen, why", [
    ([OCLGRIND, POCL], POCL, "the only CPU device"),
    ([OCLGRIND, POCL, INTEL], INTEL, "frames 11-24% faster"),
    ([POCL, INTEL, NVIDIA], NVIDIA, "the first GPU"),
    ([OCLGRIND], OCLGRIND, "only a simulator"),          # nothing else: a simulator beats nothing
])
def test_default_device(devices, chosen, why):
    keyed = [(f"{i}:0", d) for i, d in enumerate(devices)]
    key, dev, reason = default_device(keyed)
    assert dev is chosen and why in reason


def test_gpu_and_cpu_never_name_the_simulator_while_another_matches(monkeypatch):
    keyed = [("0:0", OCLGRIND), ("1:0", POCL), ("2:0", NVIDIA)]
    monkeypatch.setattr(runtime, "list_devices", lambda: keyed)
    monkeypatch.setattr(runtime, "describe", lambda d: d.platform.name)
    assert choose_device("gpu")[1] is NVIDIA and choose_device("cpu")[1] is POCL
    assert choose_device("oclgrind")[1] is OCLGRIND                     # named: used
    monkeypatch.delenv(runtime.DEVICE_ENV, raising=False)
    assert choose_device(None)[1] is NVIDIA


def test_a_bundled_runtime_is_registered_by_its_absolute_path(tmp_path, monkeypatch):
    prefix, cache, system = tmp_path / "env", tmp_path / "cache", tmp_path / "vendors"
    (prefix / "lib").mkdir(parents=True)
    (prefix / "lib" / "libintelocl.so").write_bytes(b"")
    system.mkdir()
    (system / "nvidia.icd").write_text("libnvidia-opencl.so.1\n")
    monkeypatch.setattr(runtime, "SYSTEM_VENDORS", system)
    monkeypatch.delenv(runtime.ICD_VENDORS_ENV, raising=False)
    folder = register_bundled_runtimes(prefix, cache)
    assert os.environ[runtime.ICD_VENDORS_ENV] == str(folder)
    assert (folder / "libintelocl.icd").read_text().strip() == str((prefix / "lib" / "libintelocl.so").resolve())
    assert (folder / "system-nvidia.icd").read_text() == "libnvidia-opencl.so.1\n"   # the system's stay visible
    monkeypatch.setenv(runtime.ICD_VENDORS_ENV, "/users/own")
    assert register_bundled_runtimes(prefix, cache) is None and os.environ[runtime.ICD_VENDORS_ENV] == "/users/own"
    monkeypatch.delenv(runtime.ICD_VENDORS_ENV)
    assert register_bundled_runtimes(tmp_path / "plain", cache) is None     # nothing bundled: nothing set


@pytest.mark.parametrize("platform, driver, limit", [
    ("rusticl", "22.3.6", 65_535),                      # Debian 12's Mesa: loops cut short
    ("rusticl", "25.0.7", None),                        # the limiter is gone since Mesa 25.0.0
    ("Portable Computing Language", "3.0-rc2", None),
])
def test_drivers_that_cut_loops_short_get_short_loop_shapes(platform, driver, limit):
    dev = SimpleNamespace(platform=SimpleNamespace(name=platform), driver_version=driver)
    assert runtime.loop_limit(dev) == limit
    caps = replace(NARROW_CAPS, is_cpu=True, max_work_group_size=1024, loop_limit=limit)
    tuning = Tuning.for_device(caps)
    assert (tuning.pixels_per_item, tuning.sort_wg, tuning.scan_wg * tuning.scan_groups) == (
        (1, 256, 256 * 256) if limit else (256, 1, 4))



@pytest.mark.parametrize("platform, per_block", [("Intel(R) OpenCL", True), ("Portable Computing Language", False)])
def test_split_sums_per_column_block_on_the_implementation_measured_faster_so(platform, per_block):
    """Tuning.split_sums_per_block: Intel's CPU runtime ran the backward with the split sums inside the pixel walk
    7x slower than without them; PoCL runs that walk faster than the per-block adds. GPUs keep the walk's."""
    cpu = replace(NARROW_CAPS, is_cpu=True, max_work_group_size=1024, platform=platform)
    assert Tuning.for_device(cpu).split_sums_per_block == per_block
    assert not Tuning.for_device(replace(cpu, is_cpu=False)).split_sums_per_block

def test_training_on_a_driver_that_cuts_loops_short_stops_with_the_reason(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(runtime, "loop_limit", lambda device: 65_535)
    out = tmp_path / "run"
    assert main(["train", "--iterations", "2", "-r", "4", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "loops short after 65,535 iterations" in err and "Mesa 25" in err and "dc4gs-cl devices" in err
    assert not out.exists()
