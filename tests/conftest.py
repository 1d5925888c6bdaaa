"""Shared fixtures. Tests that need the real robot data skip cleanly when ../shared is absent.

Sizes: ``make test`` (plain ``pytest``) runs every module, command and demo stage on reduced sizes; tests marked
``slow`` are the full-size runs and are deselected unless ``--full`` is given (``make test-all``). The ``full``
fixture tells a test which size it runs at."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PROPRIO_SHARED", REPO.parent / "shared"))
LWR_DIR = SHARED / "data" / "kuka_lwr4"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--full", action="store_true", default=False,
                     help="full sizes (make test-all): also run the tests marked slow, and size-parametrised "
                          "tests at their full size")


# The longest test modules and notebooks (CPU seconds of `make test`'s reduced sizes, measured one file at a time:
# docs/development/history.md), longest first. pytest-xdist (--dist loadscope --no-loadscope-reorder) hands the modules
# to the workers in collection order, so these start first and the many short modules fill in behind them (longest
# processing time first); xdist's default order, by number of tests, started the demo's seven tests last.
LONGEST_FIRST = ("test_demo.py", "test_ambiguity.py", "test_parallel.py", "test_gap.py", "06_gap_diagnosis.ipynb",
                 "test_robot_signals.py", "08_your_own_effect.ipynb", "07_hybrid_models.ipynb")


def _longest_first(item: pytest.Item) -> int:
    name = item.path.name
    return LONGEST_FIRST.index(name) if name in LONGEST_FIRST else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=_longest_first)                  # stable: every other module keeps its collection order
    if config.getoption("--full"):
        return
    slow = [item for item in items if item.get_closest_marker("slow")]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if not item.get_closest_marker("slow")]


@pytest.fixture(scope="session")
def full(request: pytest.FixtureRequest) -> bool:
    """True under ``--full`` (``make test-all``): size-parametrised tests run at their full size."""
    return bool(request.config.getoption("--full"))


@pytest.fixture(scope="session")
def benchmark_module():
    """``load(name)``: the script ``benchmarks/<name>.py`` imported as a module (benchmarks are not a package)."""
    import importlib.util

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load


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
