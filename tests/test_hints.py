"""Hints beyond the library (proprio.diagnosis.hints): an effect outside the candidate set is named by the signal it
follows, scored on held-out data, and the null case gives no hint."""
from __future__ import annotations

import json

import numpy as np
import pytest

from proprio.description import load_robot
from proprio.gap_benchmark.case_data import rfma_like_motion
from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING, GapData, SimModel, condition_all, kept
from proprio.diagnosis.hints import find_hints
from proprio.diagnosis import diagnose
from proprio.diagnosis.selection.forward import _time_blocks, attribute
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS
from proprio.recording import Recording
from proprio.signals import MotionSignals

RATE = 100.0
NOISE = 0.05
ENCODER_STD = np.radians(0.0005)
CANDIDATES = ["viscous_coulomb", "sensor_offset_gain"]


@pytest.fixture(scope="module")
def robot():
    return load_robot("iiwa14_nominal")


def _recs(robot, extra, effects=(), seeds=(1, 2, 3), duration=14.0, session=(0.0, 0.0, 0.0)):
    """2 training + 1 held-out recordings: rigid body + library ``effects`` + ``extra(t_session, q, tau) -> Δτ``
    (the out-of-library term) + white noise; encoder q and τ only, as a robot logs."""
    out = []
    for seed, t0 in zip(seeds, session):
        t, q, qd, qdd, _ = rfma_like_motion(robot, seed, duration, RATE)
        s = MotionSignals(t, q, qd, qdd)
        tau = inverse_dynamics(robot, q, qd, qdd)
        for eff in effects:
            tau = tau + eff.torque(s.with_tau(tau))
        tau = tau + extra(t + t0, q, tau)
        rng = np.random.default_rng(100 + seed)
        tau = tau + rng.normal(0.0, NOISE, tau.shape)
        q_meas = q + rng.normal(0.0, ENCODER_STD, q.shape)
        meta = {"robot": robot.name} | ({"session_time_s": t0} if any(session) else {})
        out.append(Recording(t=t, q=q_meas, tau=tau, meta=meta))
    return out[:2], out[2:]


def _on(j, f):
    def extra(t, q, tau):
        d = np.zeros_like(tau)
        d[:, j] = f(t, q, tau)
        return d
    return extra


def _model(robot):
    return SimModel(robot, (EFFECTS["torque_noise"](robot.n, std=NOISE),))


def test_cross_talk_is_hinted_as_tau_of_the_neighbour_and_reported_as_a_hint(robot, tmp_path):
    n = robot.n
    rng = np.random.default_rng(7)
    friction = EFFECTS["viscous_coulomb"](n, coulomb=rng.uniform(0.2, 0.4, n), viscous=rng.uniform(0.1, 0.3, n))
    train, hold = _recs(robot, _on(0, lambda t, q, tau: 0.02 * tau[:, 1]), effects=(friction,))
    d = diagnose(_model(robot), train, hold, tmp_path, candidates=CANDIDATES)
    att = d.attribution
    assert att.steps and att.steps[0].name == "viscous_coulomb"        # the library effect is still named ...
    hint = next(h for h in att.hints if h.joint == 0)                   # ... and the cross-talk is a hint
    assert hint.signals[0] == "tau_2" and hint.terms[0] == "τ₂"
    assert hint.coefficients[0] == pytest.approx(0.02, rel=0.1)
    assert hint.gain > 0.5 and hint.t_stat > 3
    assert "joint 1's remaining residual follows τ of joint 2" in hint.text and "held-out gain" in hint.text
    assert all(s.name in att.candidates for s in att.steps)             # never reported as a library effect
    md = d.files["report_md"].read_text()
    assert "## Hints beyond the library" in md and "| τ₂" in md
    assert "Hint: joint 1's remaining residual" in d.explanation
    js = json.loads(d.files["json"].read_text())
    assert js["hints"][0]["signals"][0] == "tau_2" and js["hints"][0]["joint"] == 0
    assert "Hints beyond the library" in d.files["report_html"].read_text()


def test_position_dependent_term_is_hinted_as_q3(robot):
    train, hold = _recs(robot, _on(2, lambda t, q, tau: 0.3 * np.sin(2 * q[:, 2])), seeds=(4, 5, 6))
    att = attribute(_model(robot), train, hold, candidates=CANDIDATES)
    assert att.residual.structured_time[2] or att.residual.structured_state[2]
    assert [h.joint for h in att.hints] == [2]
    assert att.hints[0].signals[0] == "q_3" and att.hints[0].terms[0] == "sin(2q₃)"
    assert att.hints[0].coefficients[0] == pytest.approx(0.3, rel=0.15)


def test_a_drift_in_session_time_is_hinted_as_time(robot):
    # 0.004 N·m/s on joint 4 over a session: recordings 14 s long, started at 0, 60 and 120 s of the session clock
    train, hold = _recs(robot, _on(3, lambda t, q, tau: 0.004 * t), seeds=(7, 8, 9), session=(0.0, 60.0, 120.0))
    att = attribute(_model(robot), train, hold, candidates=["viscous_coulomb"])
    hint = next(h for h in att.hints if h.joint == 3)
    assert hint.signals[0] == "time"
    assert hint.coefficients[0] == pytest.approx(0.004, rel=0.15)


def test_null_case_gives_no_hint(robot):
    train, hold = _recs(robot, lambda t, q, tau: np.zeros_like(tau), seeds=(11, 12, 13))
    model = _model(robot)
    att = attribute(model, train, hold, candidates=CANDIDATES)
    assert att.hints == []
    # forced onto every joint (not only structured ones), the held-out test alone keeps the null clean
    ct = condition_all(train, DIAGNOSIS_CONDITIONING, "training")
    ch = condition_all(hold, DIAGNOSIS_CONDITIONING, "holdout")
    tr = GapData.build(model, ct, [kept(c, 0.5) for c in ct], "training")
    ho = GapData.build(model, ch, [kept(c, 0.5) for c in ch], "holdout")
    assert find_hints(tr, ho, tr.residual, ho.residual, range(robot.n), _time_blocks(ho, att.block_s)) == []
