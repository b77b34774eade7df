"""Shared fixtures: the OpenCL runtime, fresh random generators (seed printed for reproduction), and the
real scenes beside the repository (tests that need them skip with the reason when they are absent)."""
from __future__ import annotations

import os
import secrets
from pathlib import Path

import numpy as np
import pytest

from dc4gs_cl.runtime import Runtime

DATA_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SEED_ENV = "DC4GS_TEST_SEED"   # set to reproduce a failing draw


@pytest.fixture(scope="session")
def rt() -> Runtime:
    """The device the tests run on ($DC4GS_DEVICE, else the default: runtime.default_device)."""
    return Runtime(profiling=True)


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A fresh generator per test; its seed is printed so a failure can be replayed with DC4GS_TEST_SEED."""
    seed = int(os.environ.get(SEED_ENV) or secrets.randbits(32))
    print(f"{SEED_ENV}={seed}")
    request.node.user_properties.append(("seed", seed))
    return np.random.default_rng(seed)


def scene_path(name: str) -> Path:
    path = DATA_DIR / name
    if not path.is_dir():
        pytest.skip(f"real scene {path} not found (the shared data folder is not beside the repository)")
    return path
