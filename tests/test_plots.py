"""The plots layer: every figure function writes a PNG atomically from plain arrays; nothing else imports
matplotlib, and the CLI's start-up does not load it."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from proprio.plots.estimation import plot_force_estimates
from proprio.plots.experiments import plot_model_grid, plot_payload_errors
from proprio.plots.gap import plot_before_after, plot_gap_map, plot_spectra
from proprio.plots.hysteresis import plot_hysteresis_loops
from proprio.plots.recording import plot_q_tau
from proprio.plots.trajectory import plot_flange_path

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
rng = np.random.default_rng(0)
t = np.linspace(0.0, 2.0, 50)
q = rng.normal(size=(50, 2))
names = ["a1", "a2"]

CASES = {
    "q_tau": lambda p: plot_q_tau(p, t, q, q, names, "x"),
    "flange": lambda p: plot_flange_path(p, t, q, rng.normal(size=(50, 3)), np.abs(q[:, 0]), names),
    "gap_map": lambda p: plot_gap_map(p, np.full((2, 3), 1 / 6), [("speed", "slow"), ("speed", "fast"),
                                                                   ("payload", "0 kg")], names),
    "spectra": lambda p: plot_spectra(p, t, np.abs(q), t, np.abs(q), names),
    "before_after": lambda p: plot_before_after(p, t, q, 0.5 * q, names, ["hysteresis"], np.ones((2, 2))),
    "force": lambda p: plot_force_estimates(p, t, {"jacobian": rng.normal(size=(50, 6))}, rng.normal(size=(50, 3)),
                                            t > 1.5, t < 0.1, 0.2, 0.2, "f"),
    "hysteresis": lambda p: plot_hysteresis_loops(p, [(0, t, q[:, 0], q[:, 1])], "h"),
    "grid": lambda p: plot_model_grid(p, ["m1", "m2"], np.array([1.0, 2.0]), np.array([1.5, 2.5])),
    "payload": lambda p: plot_payload_errors(p, [0.5, 1.0], {"ours": np.ones((2, 3)), "ref": 2 * np.ones((2, 3))},
                                             "ref", "p"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_figure_is_a_png_and_leaves_no_temp(case, tmp_path):
    path = tmp_path / "sub" / f"{case}.png"
    assert CASES[case](path) == path
    assert path.read_bytes()[:8] == PNG_MAGIC and path.stat().st_size > 2000
    assert [p.name for p in path.parent.iterdir()] == [path.name]      # atomic: no temporary left beside it


def test_cli_start_up_does_not_load_matplotlib():
    code = "import sys, proprio.cli, proprio.inspection, proprio.systems.rfma; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
