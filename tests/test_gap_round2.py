"""The diagnosis on real arms, round 2 (issue 39), on the Drake twin: a log without its gravity torque, a
configuration-dependent torque that is not hysteresis, and the data path that never makes the "before" gap."""
from __future__ import annotations

import numpy as np
import pytest

from proprio.diagnosis.data import SimModel
from proprio.diagnosis.selection.forward import attribute
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS
from proprio.gap_benchmark.case_data import generate_twin_case_data
from proprio.gap_benchmark.cases import BenchmarkCase, make_cases
from proprio.gap_benchmark.run import _flagged_unexplained, _hint_names_signal, run_case


def _model(data, drop=()):
    n = data.robot.n
    return SimModel(data.robot, tuple(EFFECTS[k](n, **data.model_params[k]) for k in data.model_effects
                                      if k not in drop))


def test_log_without_gravity_names_gravity_not_offsets():
    """τ logged without its gravity part (a drive that compensates it): the finding names gravity; no offsets are
    named; the same data with gravity give no such finding."""
    data = generate_twin_case_data(BenchmarkCase("twin:no-gravity", (), 1.0, 1234, twin=True))

    def strip(r):
        q = r.truth["q_true"]
        return r.replace(tau=r.tau - inverse_dynamics(data.robot, q, np.zeros_like(q), np.zeros_like(q)))

    model = _model(data)
    att = attribute(model, [strip(r) for r in data.train], [strip(r) for r in data.holdout])
    assert att.missing_term is not None and att.missing_term.term == "gravity"
    assert 1 in att.missing_term.joints                                   # joint 2 carries the arm's weight
    assert all(abs(a + 1.0) < 0.1 for a in att.missing_term.coefficients)
    assert "sensor_offset" not in att.top(3)
    assert "exclude gravity" in att.missing_term.text(att.joint_names)
    assert attribute(model, data.train, data.holdout).missing_term is None


def test_spring_and_cable_are_position_not_history():
    """A gravity-compensation spring k (q − q₀) on one joint and a cable's sin q on another: no library effect above
    5 % held-out gain (no hysteresis), and a hint on q."""
    case = next(c for c in make_cases(twin=True) if c.name == "twin:open:spring_cable@1")
    r = run_case(case)
    assert r.error is None
    assert all(g < 0.05 for g in r.physical_gains.values()), r.physical_gains
    assert _flagged_unexplained(r)
    assert _hint_names_signal(r), r.hints
