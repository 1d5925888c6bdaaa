"""The one friction law (proprio.friction_law): every stage that evaluates ``F_v q̇ + F_c sgn(q̇)`` goes through it, with
one smoothing, so a change of the law's smoothing changes the twin, the diagnosis, the identification, the learning
backbone and the estimator alike."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from proprio import friction_law
from proprio.description import load_robot
from proprio.diagnosis.candidates.base import EffectCandidate
from proprio.diagnosis.data import SimModel
from proprio.diagrams.estimation import RigidBodyTorqueModel
from proprio.diagrams.twin import TwinConfig
from proprio.dynamics import inverse_dynamics
from proprio.effects import Motor, ViscousCoulomb, robot_friction
from proprio.identification.regressor import regressor_buffer
from proprio.learning.features import rbd_provider
from proprio.signals import MotionSignals
from proprio.systems.joint_drive import AddJointDrive, FrictionDrive, JointDrive

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def robot():
    return load_robot("iiwa14_identified")


def _motion(n: int, rng: np.random.Generator, size: int = 40):
    """States where the smoothing matters: |q̇| up to 0.15 rad/s, both signs, and exact rests."""
    q = rng.uniform(-1.0, 1.0, (size, n))
    qd = rng.uniform(-0.15, 0.15, (size, n))
    qd[::7] = 0.0
    return q, qd, rng.uniform(-1.0, 1.0, (size, n))


def _twin_step_friction(robot, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The twin's link friction with the description's coefficients: per step (the drive's actuation output for zero
    motor torque, one sample at a time) by the drive the twin builds for it (the C++ :class:`FrictionDrive`) and by
    the Python :class:`JointDrive` (the drive of twins with plugins, pre-sliding, coupled or elastic drives), and in
    batch (``link_torque``). The effect is built by the twin's own config loader from a block that sets no
    smooth_velocity."""
    config = TwinConfig.from_dict({"robot": robot.name, "effects": {"viscous_coulomb": {
        "viscous": list(robot.friction_viscous), "coulomb": list(robot.friction_coulomb)}}}, "test")
    link = [e for e in config.effects if e.place == "link"]
    twin_drive = AddJointDrive(DiagramBuilder(), robot.n, link)
    assert isinstance(twin_drive, FrictionDrive)
    per_step = []
    for drive in (twin_drive, JointDrive(robot.n, link)):
        ctx = drive.CreateDefaultContext()
        drive.GetInputPort("motor_torque").FixValue(ctx, np.zeros(robot.n))
        per_step.append([])
        for qk, qdk in zip(q, qd):
            drive.GetInputPort("link_state").FixValue(ctx, np.concatenate([qk, qdk]))
            per_step[-1].append(-drive.GetOutputPort("actuation").Eval(ctx))
    return np.array(per_step[0]), np.array(per_step[1]), twin_drive.link_torque(np.zeros(len(q)), q, qd)


def _every_stage(robot, q, qd, qdd) -> dict[str, np.ndarray]:
    """Link friction [N·m] ``[N,n]`` of the description's coefficients as each stage evaluates it."""
    fv, fc = np.asarray(robot.friction_viscous), np.asarray(robot.friction_coulomb)
    rigid = inverse_dynamics(robot, q, qd, qdd)
    s = MotionSignals(np.zeros(len(q)), q, qd, qdd)
    twin_step, python_step, twin_batch = _twin_step_friction(robot, q, qd)
    estimator = RigidBodyTorqueModel(robot)
    step = estimator.tau_int_step()
    candidate = EffectCandidate("viscous_coulomb", robot.n).proto.regressor(s)
    buf = regressor_buffer(robot, q, qd, qdd)
    jj = np.arange(robot.n)
    return {
        "twin per step (C++ drive)": twin_step,
        "twin per step (Python drive)": python_step,
        "twin batch": twin_batch,
        "diagnosis model": SimModel(robot).rigid_torque(q, qd, qdd) - rigid,
        "diagnosis candidate": np.einsum("snp,p->sn", candidate, np.concatenate([fv, fc])),
        "estimator batch": estimator.tau_int(q, qd, qdd),
        "estimator per step": np.array([step(v, a) for v, a in zip(qd, qdd)]),
        "learning backbone": rbd_provider(robot)(q, qd, qdd) - rigid,
        "identification regressor": fv * buf[jj, 12 * jj + 10].T + fc * buf[jj, 12 * jj + 11].T,
        "description effect": robot_friction(robot).torque(s),
    }


def test_every_stage_evaluates_the_one_law(robot):
    q, qd, qdd = _motion(robot.n, np.random.default_rng(0))
    law = friction_law.viscous_coulomb(qd, np.asarray(robot.friction_viscous), np.asarray(robot.friction_coulomb))
    for stage, tau in _every_stage(robot, q, qd, qdd).items():
        np.testing.assert_allclose(tau, law, rtol=0, atol=1e-12, err_msg=stage)
    assert np.all(law * qd >= 0)                             # dissipative
    assert np.all(law[qd == 0] == 0)


def test_a_change_of_the_smoothing_changes_every_stage_alike(robot, monkeypatch):
    q, qd, qdd = _motion(robot.n, np.random.default_rng(1))
    before = _every_stage(robot, q, qd, qdd)
    monkeypatch.setattr(friction_law, "SMOOTH_VELOCITY", 0.2)          # a user's change of the one smoothing
    after = _every_stage(robot, q, qd, qdd)
    fv, fc = np.asarray(robot.friction_viscous), np.asarray(robot.friction_coulomb)
    expected = fv * qd + fc * np.tanh(qd / 0.2)
    change = expected - (fv * qd + fc * np.tanh(qd / 0.05))
    assert np.max(np.abs(change)) > 0.05                                # N·m: the change is visible
    for stage in before:
        np.testing.assert_allclose(after[stage], expected, rtol=0, atol=1e-12, err_msg=stage)
        np.testing.assert_allclose(after[stage] - before[stage], change, rtol=0, atol=1e-12, err_msg=stage)


def test_an_effect_setting_overrides_the_smoothing_for_that_effect_only():
    vc = ViscousCoulomb(2, viscous=0.0, coulomb=1.0, smooth_velocity=[0.01, 0.1])
    qd = np.array([[0.01, 0.01]])
    np.testing.assert_allclose(vc.friction(qd), np.tanh([[1.0, 0.1]]), rtol=1e-12)
    assert Motor(2).smooth_velocity.tolist() == [friction_law.SMOOTH_VELOCITY] * 2
    assert ViscousCoulomb(2).smooth_velocity.tolist() == [friction_law.SMOOTH_VELOCITY] * 2


def test_the_law_and_its_limits():
    qd = np.array([-1.0, -1e-3, 0.0, 1e-3, 1.0])
    np.testing.assert_array_equal(friction_law.smooth_sign(qd, 0.0), np.sign(qd))       # v_s = 0: the exact sign
    np.testing.assert_allclose(friction_law.smooth_sign(qd, 0.05), np.tanh(qd / 0.05), rtol=1e-15)
    h = 1e-7
    slope = (friction_law.viscous_coulomb(h, 0.3, 0.2) - friction_law.viscous_coulomb(-h, 0.3, 0.2)) / (2 * h)
    assert slope == pytest.approx(friction_law.slope_at_rest(0.3, 0.2), rel=1e-6)
    assert friction_law.slope_at_rest(0.3, 0.2) == pytest.approx(0.3 + 0.2 / friction_law.SMOOTH_VELOCITY)


def test_the_description_friction_is_the_viscous_coulomb_effect(robot, lwr_dir):
    vc = robot_friction(robot)
    assert isinstance(vc, ViscousCoulomb)
    assert vc.viscous.tolist() == list(robot.friction_viscous) and vc.coulomb.tolist() == list(robot.friction_coulomb)
    assert robot_friction(robot.without_friction()) is None
    lwr = load_robot(lwr_dir)                                # the LWR robot.yaml still loads
    assert lwr.n == 7
    assert (robot_friction(lwr) is None) == (not lwr.has_friction)


_OWN_SIGN = re.compile(r"np\.(sign|tanh)\([^)]*\b(qd|q_dot|theta_dot|velocity)")


def test_no_other_module_evaluates_a_friction_sign_of_its_own():
    """Regression (issue 21): friction's sign of q̇ was written in seven places with three laws."""
    offenders = [f"{p.relative_to(ROOT)}:{i}" for p in (ROOT / "proprio").rglob("*.py") if p.name != "friction_law.py"
                 for i, line in enumerate(p.read_text().splitlines(), 1) if _OWN_SIGN.search(line)]
    assert offenders == []
