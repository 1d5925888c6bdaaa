"""Verdicts that cannot mislead (issue 22, item 2): one test per rule, on small synthetic cases of the iiwa at 100 Hz
(encoder q and τ only, the model the truth's rigid body)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from proprio.description import load_robot
from proprio.gap_benchmark.case_data import rfma_like_motion
from proprio.diagnosis.data import SimModel
from proprio.diagnosis.patch import twin_patch
from proprio.diagnosis.report.document import _ranking_table
from proprio.diagnosis.residual import ResidualStructure
from proprio.diagnosis.selection.forward import attribute
from proprio.diagnosis.report.verdict import data_and_processing_text, undecided_text
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS
from proprio.recording import Recording
from proprio.signals import MotionSignals

RATE = 100.0


@pytest.fixture(scope="module")
def robot():
    return load_robot("iiwa14_nominal")


def _recs(robot, effects, seeds, duration, noise, encoder_std=1e-6, ar=0.0):
    """Recordings of the RFMA-like motion: τ = rigid body + ``effects`` + noise of σ ``noise`` [N·m] (white, or AR(1)
    with coefficient ``ar``: autocorrelated, structured), q with white encoder noise ``encoder_std`` [rad]."""
    out = []
    for seed in seeds:
        t, q, qd, qdd, _ = rfma_like_motion(robot, seed, duration, RATE)
        s = MotionSignals(t, q, qd, qdd)
        tau = inverse_dynamics(robot, q, qd, qdd)
        for eff in effects:
            tau = tau + eff.torque(s.with_tau(tau))
        rng = np.random.default_rng(100 + seed)
        w = rng.normal(0.0, noise, tau.shape)
        if ar:
            w = scipy.signal.lfilter([np.sqrt(1 - ar ** 2)], [1.0, -ar], w, axis=0)
        out.append(Recording(t=t, q=q + rng.normal(0.0, encoder_std, q.shape), tau=tau + w,
                             meta={"robot": robot.name}))
    return out


def test_white_only_when_both_whiteness_tests_agree():
    # joint 0 autocorrelated, joint 1 predictable from the state — both within the processing error, so neither is
    # flagged "structured" for the hints; still neither is white. Joint 2 passes both tests.
    rs = ResidualStructure(rmse=np.ones(3), ljung_box_p=np.array([1e-6, 0.5, 0.4]),
                           r2_state=np.array([0.0, 0.3, 0.01]), structured_time=np.zeros(3, bool),
                           structured_state=np.zeros(3, bool), within_processing=np.ones(3, bool),
                           white_rms=np.ones(3))
    assert rs.white_joints.tolist() == [False, False, True]
    assert not rs.white
    both = ResidualStructure(np.ones(2), np.array([0.3, 0.9]), np.array([0.0, 0.02]), np.zeros(2, bool),
                             np.zeros(2, bool), np.zeros(2, bool), np.ones(2))
    assert both.white


def test_a_structured_residual_is_neither_sensor_noise_nor_patched_as_torque_noise(robot):
    model = SimModel(robot)
    # the same level of noise, white: found as torque noise at its level (the test below could fail) ...
    recs = _recs(robot, [], (1, 2, 3), 12.0, 0.3)
    white = attribute(model, recs[:2], recs[2:], candidates=["sensor_offset_gain"])
    assert [f.name for f in white.noise] == ["torque_noise"]
    np.testing.assert_allclose(white.noise[0].rms, 0.3, rtol=0.2)
    assert "torque_noise" in twin_patch(white, model).get("effects", {})
    # ... autocorrelated (Ljung–Box p ≈ 0): structured, never noise, never in the patch
    recs = _recs(robot, [], (1, 2, 3), 12.0, 0.3, ar=0.97)
    att = attribute(model, recs[:2], recs[2:], candidates=["sensor_offset_gain"])
    assert np.all(att.residual.ljung_box_p < 0.01) and not att.residual.white
    assert att.noise == []
    assert "torque_noise" not in twin_patch(att, model).get("effects", {})
    assert all(r["gain"] >= 0.0 for r in att.ranking)                # rule: no negative gains in rankings
    rank = _ranking_table(att)
    assert " -" not in rank and "| -" not in rank


def test_undecided_names_the_leader_its_gain_and_the_seconds_needed(robot):
    n = robot.n
    fc = np.zeros(n)
    fc[1] = 0.6
    eff = EFFECTS["viscous_coulomb"](n, coulomb=fc, viscous=np.zeros(n))
    train = _recs(robot, [eff], (1, 2), 14.0, 0.5, ar=0.95)
    hold = _recs(robot, [eff], (3,), 6.0, 0.5, ar=0.95)        # too little held-out data for this effect
    att = attribute(SimModel(robot), train, hold, candidates=["viscous_coulomb"], trim_s=0.3)
    assert att.steps == []
    u = att.undecided
    assert u is not None and u.name == "viscous_coulomb"
    assert u.gain >= 0.02 and 0.0 < u.t_stat < u.t_crit
    assert u.more_s > 0.0
    # the seconds follow t ∝ √blocks: the blocks needed bring t to the bound
    blocks = u.n_blocks + u.more_s / u.block_s
    assert u.t_stat * np.sqrt(blocks / u.n_blocks) == pytest.approx(u.t_crit, rel=1e-6)
    text = undecided_text(att)
    assert text.startswith("Undecided") and "viscous + Coulomb friction" in text
    assert f"{100 * u.gain:.0f} %" in text and f"{u.more_s:.0f} s more held-out data" in text


def test_only_data_path_candidates_are_filed_as_data_path(robot):
    # a real friction on joint 2, significant, but within the torque error of derivatives from a very noisy encoder:
    # it is not named — and not filed as a data-path finding either
    n = robot.n
    fc = np.zeros(n)
    fc[1] = 0.4
    eff = EFFECTS["viscous_coulomb"](n, coulomb=fc, viscous=np.zeros(n))
    recs = _recs(robot, [eff], (1, 2, 3), 12.0, 0.01, encoder_std=1e-3)
    att = attribute(SimModel(robot), recs[:2], recs[2:], candidates=["viscous_coulomb", "payload"])
    assert att.processing_steps == [] and att.physical_steps == []
    assert [b[0] for b in att.below_floor] == ["viscous_coulomb"]
    assert "Within the conditioning error: viscous + Coulomb friction" in data_and_processing_text(att)
    assert "Data path:" not in data_and_processing_text(att)


def test_diagnose_model_takes_an_identified_model_file(tmp_path):
    """``diagnose --model M.npz`` (item 4): the model under diagnosis is the identified one — its inertials, its
    viscous/Coulomb friction and its torque offsets — so "my identified model vs new data" is one command."""
    import argparse

    from proprio.cli.diagnose import _model
    from proprio.identification.estimators import identify
    from proprio.identification.excitation import FourierTrajectory
    from proprio.identification.model_io import load_model, save_model

    robot = load_robot("iiwa14_identified")
    rng = np.random.default_rng(1)
    traj = FourierTrajectory(rng.uniform(-0.4, 0.4, (7, 5)), rng.uniform(-0.4, 0.4, (7, 5)), 0.1 * np.pi)
    q, qd, qdd = traj.evaluate(np.linspace(0.0, 20.0, 2000, endpoint=False))
    offsets = np.linspace(-0.5, 0.5, robot.n)
    tau = inverse_dynamics(robot, q, qd, qdd) + np.array(robot.friction_viscous) * qd \
        + np.array(robot.friction_coulomb) * np.sign(qd) + offsets
    path = save_model(identify(robot, q, qd, qdd, tau, method="ols", offsets=True), tmp_path / "ident.npz")
    ident = load_model(path)
    args = argparse.Namespace(model=str(path), effects=[], effects_config=None)
    model = _model(args)
    assert model.robot.has_friction and "sensor_offset_gain" in model.effect_names
    moving = np.abs(qd) > 5.0 * ident.coulomb_velocity_scale   # [N, n]: away from the smoothed sign, tanh(5) ≈ 1
    assert moving.sum() > 0.5 * moving.size
    pred = model.predict(MotionSignals(np.arange(len(q)) / 100.0, q, qd, qdd, tau))
    np.testing.assert_allclose(pred[moving], ident.torque(q, qd, qdd)[moving], atol=1e-6 * np.abs(tau).max() + 1e-6)
    np.testing.assert_allclose(pred[moving], tau[moving], atol=0.05)       # and it is the robot that made the data


def test_a_stand_in_taken_first_is_dropped_once_the_effects_it_imitated_are_named():
    """The offline pair rigid body + viscous/Coulomb friction (the gap benchmark's draw): with a Bonferroni bound as
    strict as the full candidate set's, step 1 takes Stribeck friction — Coulomb friction alone is not yet significant
    beside the rigid-body error — and steps 2–3 name the rigid body and viscous + Coulomb friction. Added last to those
    two, Stribeck lowers the held-out error by less than nothing: the backward check drops it, and the verdict names
    the two true effects only and says what was dropped."""
    from proprio.gap_benchmark.case_data import generate_case_data
    from proprio.gap_benchmark.cases import BenchmarkCase
    from proprio.diagnosis.report.verdict import data_and_processing_text

    case = BenchmarkCase("rigid_body+viscous_coulomb", ("rigid_body", "viscous_coulomb"), 1.0, 407510091)
    data = generate_case_data(case)
    n = data.robot.n
    model = SimModel(data.robot, tuple(EFFECTS[k](n, **data.model_params[k]) for k in data.model_effects))
    said: list[str] = []
    att = attribute(model, data.train, data.holdout, candidates=["stribeck", "viscous_coulomb", "rigid_body"],
                    alpha=0.01 * 3 / 11, progress=said.append)
    assert [m for m in said if "added" in m][0].startswith("step 1: added stribeck")     # the forward path's stand-in
    assert [s.name for s in att.physical_steps] == ["rigid_body", "viscous_coulomb"]
    assert [(x.name, x.step) for x in att.superseded] == [("stribeck", 1)]
    assert att.superseded[0].gain < 0.02 and att.superseded[0].context == ["rigid_body", "viscous_coulomb"]
    assert set(att.fitted) == {"rigid_body", "viscous_coulomb"} and "stribeck" not in att.steps[-1].params
    assert "A stand-in, dropped: Stribeck" in data_and_processing_text(att)


def test_torque_noise_is_named_from_the_raw_floor_where_the_residual_is_within_the_conditioning_error(robot):
    # a friction on joint 2 within the torque error of derivatives from a very noisy encoder: its residual is
    # structured (not white) but within the conditioning error, so the whiteness test cannot decide about noise there
    n = robot.n
    fc = np.zeros(n)
    fc[1] = 0.4
    eff = EFFECTS["viscous_coulomb"](n, coulomb=fc, viscous=np.zeros(n))
    cands = ["viscous_coulomb", "payload"]

    def run(model, noise):
        recs = _recs(robot, [eff], (1, 2, 3), 12.0, noise, encoder_std=1e-3)
        return attribute(model, recs[:2], recs[2:], candidates=cands)

    att = run(SimModel(robot), 0.05)
    rs = att.residual
    level = rs.within_processing & ~rs.white_joints
    assert level[1]                                       # the case the rule is for
    # the model lacks the τ noise: named from the raw τ's white floor, at its level, on those joints only
    assert [f.name for f in att.noise] == ["torque_noise"]
    rms = att.noise[0].rms
    assert rms[1] > 0 and np.all(rms[~(level | rs.white_joints)] == 0)
    np.testing.assert_allclose(rms[level], 0.05, rtol=0.1)
    assert "within the conditioning error" in att.noise[0].explanation
    np.testing.assert_allclose(twin_patch(att, SimModel(robot))["effects"]["torque_noise"]["std"], rms)
    # the model carries it: not named
    noisy = SimModel(robot, (EFFECTS["torque_noise"](n, std=np.full(n, 0.05)),))
    assert run(noisy, 0.05).noise == []
    # a τ low-passed before logging (as the LWR 4+ logs are) has a coloured floor: not named there
    b, a = scipy.signal.butter(2, 0.3)
    recs = [r.replace(tau=r.tau + scipy.signal.lfilter(b, a, np.random.default_rng(7 + k).normal(0.0, 0.05, r.tau.shape),
                                                       axis=0))
            for k, r in enumerate(_recs(robot, [eff], (1, 2, 3), 12.0, 0.0, encoder_std=1e-3))]
    low = attribute(SimModel(robot), recs[:2], recs[2:], candidates=cands)
    assert low.residual.within_processing[1] and not low.residual.white_joints[1]
    assert not low.noise or low.noise[0].rms[1] == 0
