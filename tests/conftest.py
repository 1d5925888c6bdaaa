"""Shared fixtures. Tests that need the real robot data skip cleanly when ../shared is absent."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PROPRIO_SHARED", REPO.parent / "shared"))
LWR_DIR = SHARED / "data" / "kuka_lwr4"


@pytest.fixture(scope="session")
def lwr_dir() -> Path:
    if not (LWR_DIR / "robot.yaml").exists():
        pytest.skip(f"real LWR 4+ data not found at {LWR_DIR}")
    return LWR_DIR


@pytest.fixture(scope="session")
def iiwa():
    from proprio.description import load_robot
    return load_robot("iiwa14_identified")


@pytest.fixture(scope="session")
def iiwa_nominal():
    from proprio.description import load_robot
    return load_robot("iiwa14_nominal")
