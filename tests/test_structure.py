"""The package's layering, read from the import statements of every module: render knows nothing of the
backward or of training, the backward nothing of training, and production code never uses the float64
test references; the settings, the run folder, report and export import without an OpenCL runtime."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "dc4gs_cl"


def imported_modules(path: Path) -> set[str]:
    """Absolute dc4gs_cl module names a file imports (relative imports resolved)."""
    package = ["dc4gs_cl", *path.relative_to(ROOT).parent.parts]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("dc4gs_cl")}
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            name = ".".join(base + ([node.module] if node.module else []))
            if name.startswith("dc4gs_cl"):
                out.add(name)
                out |= {f"{name}.{a.name}" for a in node.names}   # "from . import ops" imports a module too
    return out


def modules(folder: str = "") -> dict[str, set[str]]:
    return {str(p.relative_to(ROOT)): imported_modules(p) for p in sorted((ROOT / folder).rglob("*.py"))}


COMMANDS = ("dc4gs_cl.apps", "dc4gs_cl.cli")
LOOP = ("dc4gs_cl.train", "dc4gs_cl.run_folder") + COMMANDS
FORBIDDEN = {   # folder -> packages its modules must not import: the layers above it
    "render": ("dc4gs_cl.backward", "dc4gs_cl.optim", "dc4gs_cl.densify", "dc4gs_cl.config") + LOOP,
    "backward": ("dc4gs_cl.optim", "dc4gs_cl.densify", "dc4gs_cl.config") + LOOP,
    "optim": ("dc4gs_cl.densify",) + LOOP,
    "densify": LOOP,
    "train": COMMANDS,
}


@pytest.mark.parametrize("folder", FORBIDDEN)
def test_lower_layers_do_not_import_higher_ones(folder):
    bad = {m: sorted(i for i in imports if i.startswith(FORBIDDEN[folder])) for m, imports in modules(folder).items()}
    assert not {m: i for m, i in bad.items() if i}


REFERENCE_USERS = {"apps/bench.py"}   # `dc4gs-cl bench` reports each stage's error against the references


def test_production_code_does_not_import_the_references():
    users = {m for m, imports in modules().items()
             if not m.startswith("reference/") and any(i.startswith("dc4gs_cl.reference") for i in imports)}
    assert users == REFERENCE_USERS


def test_the_import_reader_sees_imports():
    """The checks above are only as good as this reader: it finds relative imports of each form."""
    trainer = imported_modules(ROOT / "train" / "trainer.py")
    assert {"dc4gs_cl.backward", "dc4gs_cl.optim.trainable", "dc4gs_cl.run_folder"} <= trainer
    assert "dc4gs_cl.densify.ops" in imported_modules(ROOT / "densify" / "strategy.py")


DEVICE_FREE = ("dc4gs_cl.config", "dc4gs_cl.statistics", "dc4gs_cl.run_folder", "dc4gs_cl.apps.report",
               "dc4gs_cl.apps.export", "dc4gs_cl.cli")
# what those must not reach: the OpenCL runtime, and the scene readers' libraries (the names the settings and the
# command line take from scene/: test splits, the built-in scene's name, path kinds, live in modules without them)
HEAVY = ("pyopencl", "pycolmap", "OpenImageIO")


@pytest.mark.parametrize("library", HEAVY)
def test_settings_run_folder_report_and_export_import_without_opencl_or_the_scene_readers(library):
    """`report` and `export` need no device, and the command line and the settings no scene reader: what they
    import must not reach these libraries (here made unimportable, one at a time)."""
    code = f"import sys; sys.modules[{library!r}] = None\nfor name in {DEVICE_FREE!r}: __import__(name)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr


def test_the_strategies_are_the_settings_strategy_names():
    """config.STRATEGY_NAMES validates --strategy without importing the strategies; it must name each of them."""
    from dc4gs_cl.config import STRATEGY_NAMES
    from dc4gs_cl.densify import STRATEGIES
    assert tuple(STRATEGIES) == STRATEGY_NAMES


def test_kernels_pass_no_16_wide_vector_through_a_built_in():
    """PoCL 3.0 on a CPU with AVX-512 that its LLVM takes for one without (Zen 4 as znver3) passes float16 values
    to and from its built-in library by two ABIs: vload16 returned garbage and every GPU-shape backward test failed
    there, passing everywhere else. No kernel calls a built-in with a 16-wide vector (raster.h loads halves)."""
    import re
    wide = re.compile(r"\b(vload|vstore|vloada?_half|vstorea?_half)16\b|\bconvert_\w+16\b|\bas_\w+16\b")
    found = [f"{p.name}:{i}" for p in sorted((ROOT / "kernels").iterdir()) if p.suffix in (".cl", ".h")
             for i, line in enumerate(p.read_text().splitlines(), 1) if wide.search(line.split("//")[0])]
    assert not found, found
