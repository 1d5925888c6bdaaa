"""Every notebook lets the reader change something (an ipywidgets control) — `make test` executes them (nbmake)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
CONTROL = re.compile(r"\b(interact|interactive)\(|widgets\.(\w*Slider|Checkbox|ToggleButtons|Dropdown|Button)\(")


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 7


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_every_notebook_has_an_interactive_control(path):
    code = "\n".join("".join(c["source"]) for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code")
    assert "import ipywidgets" in code and CONTROL.search(code), f"{path.name} has no ipywidgets control"
