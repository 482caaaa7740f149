"""Shared fixtures: locations and small synthetic scenes."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
# Compiled MuJoCo scenes of this test session go to a fresh folder (subprocesses inherit it),
# removed when the session ends (each run writes about 170 MB there).
_OWN_CACHE_DIR: str | None = None
if "DREAM_CACHE_DIR" not in os.environ:
    _OWN_CACHE_DIR = tempfile.mkdtemp(prefix="dream-test-cache-")
    os.environ["DREAM_CACHE_DIR"] = _OWN_CACHE_DIR

REPO = Path(__file__).resolve().parents[1]
REALDATA = Path(os.environ.get("DREAM_REALDATA", REPO.parent / "shared" / "realdata"))


def pytest_unconfigure(config: pytest.Config) -> None:
    if _OWN_CACHE_DIR is not None:
        shutil.rmtree(_OWN_CACHE_DIR, ignore_errors=True)


@pytest.fixture(scope="session")
def realdata() -> Path:
    if not REALDATA.is_dir():
        pytest.skip(f"real data not found at {REALDATA} (set DREAM_REALDATA)")
    return REALDATA


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def panda():
    """The Panda of `example-robot-data`."""
    from dream.robot import load_robot

    return load_robot("panda")


@pytest.fixture(scope="session")
def meshes(panda):
    """The Panda's visual meshes (`dream.silhouette.load_robot_meshes`)."""
    from dream.silhouette import load_robot_meshes

    return load_robot_meshes(panda)
