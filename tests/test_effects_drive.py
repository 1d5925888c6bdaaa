"""The effects real drives have: pre-sliding friction (one Dahl law per step and in batch, shared with the gauge's
hysteresis; in the twin's drive loop), the drive candidates of the diagnosis (rotor inertia, a coupled motor's friction,
offsets) and the rule that what τ is decides the candidates."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from proprio.description import load_robot
from proprio.drive_description import drive_from_dict
from proprio.effects import Hysteresis, PreSliding
from proprio.effects.dahl import dahl_advance, dahl_start, dahl_value
from proprio.signals import MotionSignals


def _wobble(n_s: int = 4000, n: int = 3, dt: float = 1e-3, seed: int = 0) -> MotionSignals:
    """A motion with many reversals of varying amplitude per joint (and a standstill at the start)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_s) * dt
    f, a = rng.uniform(0.3, 2.0, (3, n)), np.radians(rng.uniform(0.05, 3.0, (3, n)))
    ph = rng.uniform(0, 2 * np.pi, (3, n))
    ramp = np.clip((t - 0.2) / 0.5, 0.0, 1.0)[:, None]
    arg = 2 * np.pi * f[None] * t[:, None, None] + ph[None]
    q = ramp * (a * np.sin(arg)).sum(axis=1)
    qd = np.gradient(q, dt, axis=0)
    return MotionSignals(t, q, qd, np.gradient(qd, dt, axis=0))


def test_presliding_per_step_law_equals_its_batch_form():
    s = _wobble()
    eff = PreSliding(3, level=[0.8, 1.5, 0.3], presliding_travel=np.radians([0.2, 0.5, 1.0]))
    st = eff.start(s.q[0], s.qd[0])
    steps = []
    for k in range(s.q.shape[0]):
        st, tau = eff.step(st, s.q[k], s.qd[k])
        steps.append(tau)
    batch = eff.torque(s)
    np.testing.assert_allclose(np.array(steps), batch, rtol=0, atol=1e-9)
    assert np.abs(batch).max() > 0.5 * 1.5                     # it saturates near its level
    # rate-independent: the same path at a tenth of the speed gives the same torque (without the deadband of the
    # reversal detection, which is a speed)
    eff = PreSliding(3, level=[0.8, 1.5, 0.3], presliding_travel=np.radians([0.2, 0.5, 1.0]), reversal_velocity=0.0)
    slow = MotionSignals(s.t * 10, s.q, s.qd / 10, s.qdd / 100)
    np.testing.assert_allclose(eff.torque(slow), eff.torque(s), rtol=0, atol=1e-12)


def test_hysteresis_is_the_same_dahl_law():
    """The gauge's hysteresis (load gain 0) and pre-sliding friction with the same level and travel are one law."""
    s = _wobble(seed=1)
    hyst = Hysteresis(3, saturation=0.4, saturation_travel=math.radians(1.5))
    pre = PreSliding(3, level=0.4, presliding_travel=math.radians(1.5))
    np.testing.assert_allclose(hyst.torque(s), pre.torque(s), rtol=0, atol=1e-12)
    # and the per-step law reproduces the hysteresis with a load gain (the level changes per sample)
    hyst = Hysteresis(3, saturation=0.2, load_gain=0.05, saturation_travel=math.radians(3.0))
    tau_link = 10 * np.sin(s.q * 30)
    s = s.with_tau(tau_link)
    level = hyst.saturation + hyst.load_gain * np.abs(tau_link)
    st = dahl_start(s.q[0], s.qd[0], level[0], hyst.reversal_velocity)
    out = []
    for k in range(s.q.shape[0]):
        st = dahl_advance(st, s.q[k], s.qd[k], level[k], hyst.saturation_travel / 3, hyst.reversal_velocity)
        out.append(dahl_value(st, s.q[k], hyst.saturation_travel / 3))
    np.testing.assert_allclose(np.array(out), hyst.torque(s), rtol=0, atol=1e-9)


def test_presliding_bounds_and_yaml():
    eff = PreSliding.from_config({"level": 1.0, "presliding_travel_deg": 0.3}, 2)
    np.testing.assert_allclose(eff.presliding_travel, math.radians(0.3))
    with pytest.raises(ValueError, match="presliding.presliding_travel"):
        PreSliding(2, presliding_travel=math.radians(5.0))


def test_twin_drive_applies_presliding_per_step():
    """The twin's drive applies the per-step law in its loop; the torque it applied equals the batch law on the
    logged motion (what the twin's sensed τ recomputes), to 1e-9."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource, VectorLogSink

    from pydrake.systems.primitives import TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from proprio.systems.joint_drive import AddJointDrive

    n, dt = 2, 1e-3
    eff = PreSliding(n, level=[0.7, 0.4], presliding_travel=np.radians([0.3, 0.6]))
    s = _wobble(n_s=1500, n=n, dt=dt, seed=3)
    builder = DiagramBuilder()
    drive = AddJointDrive(builder, n, [eff], time_step=dt)
    x = np.hstack([s.q, s.qd]).T
    src = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(s.t, x)))
    zero = builder.AddSystem(ConstantVectorSource(np.zeros(n)))
    builder.Connect(src.get_output_port(), drive.GetInputPort("link_state"))
    builder.Connect(zero.get_output_port(), drive.GetInputPort("motor_torque"))
    log = builder.AddSystem(VectorLogSink(n, dt))
    builder.Connect(drive.GetOutputPort("actuation"), log.get_input_port())
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.Initialize()
    sim.AdvanceTo(s.t[-1] - 0.5 * dt)
    applied = -log.FindLog(sim.get_context()).data().T
    m = min(applied.shape[0], s.q.shape[0])
    np.testing.assert_allclose(applied[:m], eff.torque(s)[:m], rtol=0, atol=1e-9)
    assert np.abs(applied).max() > 0.3


# ---- the diagnosis: drive candidates and the rule of τ's kind --------------------------------------------------

def _drive_robot(coupled: bool = False, **fields):
    robot = load_robot("iiwa14_identified")
    gear = [100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0]
    block = {"tau_kind": "drive", "gear_ratio": gear, **fields}
    if coupled:
        r = np.diag(gear)
        r[6, 5] = gear[6]
        block["coupling"] = r.tolist()
    return dataclasses.replace(robot, drive=drive_from_dict(block, robot.n))


def _gap_data(model, seed: int = 0):
    from proprio.gap_benchmark.case_data import rfma_like_motion
    from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING, GapData, condition_all, kept
    from proprio.recording import Recording

    t, q, _, _, _ = rfma_like_motion(model.robot, seed, 6.0)
    rec = Recording(t=t, q=q, tau=np.zeros_like(q), meta={"robot": model.robot.name})
    cond = condition_all([rec], DIAGNOSIS_CONDITIONING, "training")
    return GapData.build(model, cond, [kept(cond[0], 0.5)], "training")


def test_tau_kind_decides_the_candidates():
    from proprio.diagnosis.candidates.registry import candidate_set
    from proprio.diagnosis.candidates.drive import DRIVE_ONLY, GAUGE_ONLY, tau_kind
    from proprio.diagnosis.data import DiagnosisError, SimModel

    link = SimModel(load_robot("iiwa14_identified"))
    drive = SimModel(_drive_robot())
    assert (tau_kind(link.robot), tau_kind(drive.robot)) == ("link_sensor", "drive")
    names_link = {c.name for c in candidate_set(link, _gap_data(link))}
    names_drive = {c.name for c in candidate_set(drive, _gap_data(drive))}
    # drive torques: no strain gauge — its hysteresis, lost motion, ripple and zero are not candidates
    assert not names_drive & set(GAUGE_ONLY)
    assert {"rotor_inertia", "drive_offset", "presliding", "sensor_gain"} <= names_drive
    # the robot has link friction: an uncoupled motor's extra friction is its own candidate
    assert "motor_friction" in names_drive
    # a link-side sensor cannot see the drive's terms (and names the Dahl loop hysteresis)
    assert not names_link & set(DRIVE_ONLY)
    assert {"hysteresis", "lost_motion", "ripple", "sensor_offset"} <= names_link
    with pytest.raises(DiagnosisError, match="hysteresis \\(a drive τ cannot show it\\)"):
        candidate_set(drive, _gap_data(drive), ["hysteresis"])
    with pytest.raises(DiagnosisError, match="rotor_inertia \\(a link_sensor τ cannot show it\\)"):
        candidate_set(link, _gap_data(link), ["rotor_inertia"])


def test_drive_candidates_follow_the_coupled_law_and_patch():
    """A coupled motor's friction candidate is the identification's drive law (τ = Cᵀ(F_v,m C q̇ + F_c,m sgn_s(C q̇)));
    the model of a drive arm predicts its drive terms; a fitted candidate patches the description's drive block."""
    from proprio.diagnosis.candidates.drive import DriveCandidate
    from proprio.diagnosis.data import SimModel
    from proprio.identification.regressor import drive_torque

    truth = _drive_robot(coupled=True, rotor_inertia=[0.5] * 7, offset=[0.1] * 7,
                         motor_friction={"viscous": [0.3] * 7, "coulomb": [0.2] * 6 + [0.9]})
    model = SimModel(_drive_robot(coupled=True, rotor_inertia=[0.5] * 7, offset=[0.1] * 7,
                                  motor_friction={"viscous": [0.3] * 7, "coulomb": [0.2] * 7}))
    data = _gap_data(model)
    cand = DriveCandidate(model.robot, "motor_friction")
    a = cand.design(data)
    theta = np.zeros(14)
    theta[13] = 0.7                                       # motor 7's missing Coulomb friction
    s = data.signals[0]
    want = drive_torque(truth, s.qd, s.qdd, None) - drive_torque(model.robot, s.qd, s.qdd, None)
    np.testing.assert_allclose(np.einsum("snp,p->sn", a, theta), data.stack([want]), rtol=0, atol=1e-12)
    assert np.abs(data.stack([want])[:, 5]).max() > 0.3   # motor 7 turns with joints 6 and 7: both feel it
    assert cand.joint_of_param(7).tolist() == [-1] * 14
    patched = cand.patch(theta)["robot"]["drive"]["motor_friction"]["coulomb"]
    np.testing.assert_allclose(patched, [0.2] * 6 + [0.9])
    off = DriveCandidate(model.robot, "drive_offset")
    np.testing.assert_allclose(off.patch(np.full(7, 0.2))["robot"]["drive"]["offset"], [0.3] * 7)
    # the model's prediction carries the drive terms and the offsets of its description
    tau_model = model.predict(s)
    tau_plain = SimModel(dataclasses.replace(model.robot, drive=None)).predict(s)
    np.testing.assert_allclose(tau_model - tau_plain, drive_torque(model.robot, s.qd, s.qdd, None) + 0.1,
                               rtol=0, atol=1e-9)


def test_diagnose_refuses_recordings_of_the_other_tau_kind(tmp_path, capsys):
    """``proprio diagnose``: a Recording whose ``meta.tau_kind`` contradicts the robot description (drive torques
    against a link-sensor model) is refused before any diagnosis, naming the file and what to change."""
    from proprio.cli import main
    from proprio.gap_benchmark.case_data import rfma_like_motion
    from proprio.recording import Recording, save_recording

    robot = load_robot("iiwa14_identified")
    t, q, _, _, _ = rfma_like_motion(robot, 3, 4.0)
    path = save_recording(Recording(t=t, q=q, tau=np.zeros_like(q), meta={"robot": robot.name, "tau_kind": "drive"}),
                          tmp_path / "drive.npz")
    rc = main(["diagnose", "--model", "iiwa14_identified", "--train", str(path), "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert rc == 2 and "drive.npz: meta.tau_kind is 'drive'" in err and "tau_kind: drive" in err
