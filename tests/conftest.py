"""Shared fixtures: locations and small synthetic scenes."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
# Compiled MuJoCo scenes of this test session go to a fresh folder (subprocesses inherit it).
os.environ.setdefault("DREAM_CACHE_DIR", tempfile.mkdtemp(prefix="dream-test-cache-"))

REPO = Path(__file__).resolve().parents[1]
REALDATA = Path(os.environ.get("DREAM_REALDATA", REPO.parent / "shared" / "realdata"))


@pytest.fixture(scope="session")
def realdata() -> Path:
    if not REALDATA.is_dir():
        pytest.skip(f"real data not found at {REALDATA} (set DREAM_REALDATA)")
    return REALDATA


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
