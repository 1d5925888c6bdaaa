"""Scoring a diagnosis against the twin's truth (proprio.diagnosis.report.truth): which families were named, fitted vs
true parameters, the rigid-body torque comparison."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from proprio.description import load_robot
from proprio.gap_benchmark.case_data import rfma_like_motion
from proprio.diagnosis.data import SimModel
from proprio.diagnosis import diagnose
from proprio.diagnosis.report.truth import compare_to_truth
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS
from proprio.identification.regressor import PARAMS_PER_JOINT, parameter_names, regressor, standard_parameters
from proprio.recording import Recording
from proprio.signals import MotionSignals

RATE, NOISE = 100.0, 0.05


def _twin_like(true_robot, effects, seeds):
    """Recordings as the twin writes them: measured q, τ; the effects in meta; the exact motion in truth."""
    out = []
    for seed in seeds:
        t, q, qd, qdd, seg = rfma_like_motion(true_robot, seed, 14.0, RATE)
        s = MotionSignals(t, q, qd, qdd)
        tau_j = inverse_dynamics(true_robot, q, qd, qdd)
        tau = tau_j.copy()
        for eff in effects:
            tau = tau + eff.torque(s.with_tau(tau_j))
        rng = np.random.default_rng(seed)
        tau = tau + rng.normal(0.0, NOISE, tau.shape)
        meta = {"robot": true_robot.name, "source": "twin",
                "effects": {e.name: {k: v.tolist() for k, v in e.params().items()} for e in effects}}
        out.append(Recording(t=t, q=q + rng.normal(0.0, 1e-5, q.shape), tau=tau, meta=meta,
                             truth={"segment": seg, "q_true": q, "qd": qd, "qdd": qdd, "tau_J_true": tau_j}))
    return out[:2], out[2:]


@pytest.fixture(scope="module")
def mixture(tmp_path_factory):
    robot = load_robot("iiwa14_nominal")
    n = robot.n
    effects = [EFFECTS["viscous_coulomb"](n, viscous=np.full(n, 0.2), coulomb=np.linspace(0.15, 0.35, n)),
               EFFECTS["sensor_offset_gain"](n, offset=np.linspace(-0.5, 0.5, n)),
               EFFECTS["hysteresis"](n)]                                  # at zero amplitude: absent
    train, hold = _twin_like(robot, effects, (31, 32, 33))
    model = SimModel(robot)
    d = diagnose(model, train, hold, tmp_path_factory.mktemp("truth"),
                 candidates=["viscous_coulomb", "sensor_offset_gain", "hysteresis"])
    return d, effects, model, hold


def test_the_report_scores_twin_data_against_the_truth(mixture):
    d, effects, _, _ = mixture
    comp = d.truth
    assert comp is not None
    assert comp.present == ["friction", "sensor offset/gain"]
    assert comp.named_present == comp.present
    rows = {(r.family, r.parameter): r for r in comp.rows}
    np.testing.assert_allclose(rows["friction", "Coulomb F_c"].fitted, effects[0].coulomb, rtol=0.15)
    np.testing.assert_allclose(rows["sensor offset/gain", "offset"].fitted, effects[1].offset, atol=0.05)
    assert np.all(np.isnan(rows["hysteresis", "saturation"].fitted))           # not named, so not fitted
    md = d.files["report_md"].read_text()
    assert "## Against the twin's truth" in md and "Named 2 of the 2 effect families" in md


def test_the_rigid_body_row_compares_torques(mixture):
    """Against a robot with other inertials: the exact correction leaves nothing, none leaves all of Δτ."""
    d, _, model, hold = mixture
    true_robot = load_robot("iiwa14_identified")
    for rec in hold:
        rec.meta["robot"] = true_robot.name
    names = parameter_names(model.robot.n)
    inertial = [k for k in range(len(names)) if k % PARAMS_PER_JOINT < 10]
    # the true inertials in the model's link frames (the two descriptions place their link frames differently):
    # least squares of the model's regressor on the true robot's torques at random states
    rng = np.random.default_rng(0)
    q, qd, qdd = rng.uniform(-1, 1, (200, 7)), rng.normal(size=(200, 7)), rng.normal(size=(200, 7))
    y = regressor(model.robot, q, qd, qdd)[..., inertial].reshape(-1, len(inertial))
    phi = np.linalg.lstsq(y, inverse_dynamics(true_robot, q, qd, qdd).reshape(-1), rcond=None)[0]
    delta = phi - standard_parameters(model.robot)[inertial]
    step = dataclasses.replace(d.attribution.steps[-1], params={
        "rigid_body": (delta, np.zeros(len(inertial)), [f"δ{names[k]}" for k in inertial])})
    exact = compare_to_truth(dataclasses.replace(d.attribution, steps=[step]), model, hold)
    none = compare_to_truth(dataclasses.replace(d.attribution, steps=[]), model, hold)
    for rec in hold:
        rec.meta["robot"] = model.robot.name
    assert "rigid body" in exact.present
    assert np.all(exact.rigid_true_rms > 0.01)
    np.testing.assert_allclose(exact.rigid_left_rms, 0.0, atol=1e-8)
    np.testing.assert_allclose(none.rigid_left_rms, none.rigid_true_rms)


def test_no_truth_without_twin_meta(mixture):
    d, _, model, hold = mixture
    for rec in hold:
        rec.meta.pop("effects")
    assert compare_to_truth(d.attribution, model, hold) is None
