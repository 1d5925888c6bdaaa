"""Base parameters, OLS/WLS/SDP estimators, model file, RBD backbone system, excitation, preprocessing, CLI."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from proprio import friction_law
from proprio.description import load_robot
from proprio.dynamics import inverse_dynamics
from proprio.identification.base_parameters import base_parameters
from proprio.identification.estimators import IdentificationError, identify, ols
from proprio.identification.excitation import FourierTrajectory
from proprio.identification.regressor import regressor, standard_parameters


@pytest.fixture(scope="module")
def robot():
    return load_robot("iiwa14_identified")


@pytest.fixture(scope="module")
def base(robot):
    return base_parameters(robot)


@pytest.fixture(scope="module")
def prior(robot):
    """Same kinematics, a-priori inertials 20 % off: what the estimators start from."""
    return robot.with_inertials([dataclasses.replace(lk, mass=lk.mass * 1.2) for lk in robot.links])


@pytest.fixture(scope="module")
def data(robot):
    """One 20 s period of a random Fourier trajectory; τ from proprio.dynamics + viscous/Coulomb friction (the one
    law, at the library's smoothing, which the identification uses by default)."""
    rng = np.random.default_rng(1)
    traj = FourierTrajectory(rng.uniform(-0.4, 0.4, (7, 5)), rng.uniform(-0.4, 0.4, (7, 5)), 0.1 * np.pi)
    q, qd, qdd = traj.evaluate(np.linspace(0.0, 20.0, 2000, endpoint=False))
    tau = inverse_dynamics(robot, q, qd, qdd) + friction_law.viscous_coulomb(qd, np.array(robot.friction_viscous),
                                                                             np.array(robot.friction_coulomb))
    return q, qd, qdd, tau


def test_base_parameter_count_iiwa(robot, base):
    """QR finds 57 base parameters for the iiwa 14 with friction — the thesis' number: 43 inertial combinations
    + 7 viscous + 7 Coulomb. The gap in |R_kk| is exact (next pivot ~1e-15 of the first)."""
    assert base.n_base == 57
    assert sum(name.startswith(("Fv", "Fc")) for name in base.names) == 14
    assert base_parameters(robot, with_friction=False).n_base == 43
    assert "Izz1" in base.names[0]                      # joint 1 only sees a combination around Izz1
    rng = np.random.default_rng(7)
    q = rng.uniform(robot.lower, robot.upper, (40, 7))
    qd, qdd = rng.normal(size=q.shape), rng.normal(size=q.shape)
    y = regressor(robot, q, qd, qdd)
    phi = rng.normal(size=84)
    np.testing.assert_allclose(y @ phi, y[..., base.independent] @ base.to_base(phi), atol=1e-10)


@pytest.mark.parametrize("method", ["ols", "wls", "sdp"])
def test_noise_free_recovery(method, robot, base, prior, data):
    model = identify(prior, *data, method=method, base=base)
    true = base.to_base(standard_parameters(robot))
    np.testing.assert_allclose(model.phi_b, true, rtol=1e-8, atol=1e-8 * np.abs(true).max())
    np.testing.assert_allclose(model.torque(*data[:3]), data[3], atol=1e-7)


@pytest.mark.parametrize("method", ["ols", "sdp"])
def test_noisy_recovery_within_one_percent(method, robot, base, prior, data):
    q, qd, qdd, tau = data
    noisy = tau + np.random.default_rng(2).normal(scale=0.05, size=tau.shape)
    model = identify(prior, q, qd, qdd, noisy, method=method, base=base)
    true = base.to_base(standard_parameters(robot))
    assert np.linalg.norm(model.phi_b - true) / np.linalg.norm(true) < 0.01
    if method == "ols":                                  # σ% (eq. 4.24–4.27) is an honest standard deviation
        sigma = np.abs(model.phi_b) * model.sigma_pct / 100
        assert np.max(np.abs(model.phi_b - true) / sigma) < 5


def test_sdp_is_physically_valid_and_rebuilds_a_plant(robot, base, prior, data):
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia

    from proprio.plant import DrakeRobot

    q, qd, qdd, tau = data
    noisy = tau + np.random.default_rng(3).normal(scale=0.3, size=tau.shape)
    model = identify(prior, q, qd, qdd, noisy, method="sdp", base=base)
    desc = model.description_identified()
    for lk in desc.links:
        i = lk.inertia_matrix_link()
        si = SpatialInertia.MakeFromCentralInertia(
            lk.mass, np.asarray(lk.com_xyz), RotationalInertia(i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]))
        assert si.IsPhysicallyValid(), lk.name
    drake = DrakeRobot(desc.without_friction())
    ours = model.torque(q[:3], qd[:3], qdd[:3]) - friction_law.viscous_coulomb(
        qd[:3], np.array(desc.friction_viscous), np.array(desc.friction_coulomb), model.coulomb_velocity_scale)
    ref = np.array([drake.inverse_dynamics(*x) for x in zip(q[:3], qd[:3], qdd[:3])])
    np.testing.assert_allclose(ours, ref, atol=1e-8)


def test_errors_name_the_unidentifiable_parameters(robot, base, data):
    q, qd, qdd, tau = data
    bad = tau.copy()
    bad[5, 2] = np.nan
    with pytest.raises(IdentificationError, match=r"tau contains 1 NaN.*sample 5, joint 3"):
        ols(robot, q, qd, qdd, bad, base=base)
    with pytest.raises(IdentificationError, match="too short.*Izz1"):
        ols(robot, q[:5], qd[:5], qdd[:5], tau[:5], base=base)
    frozen = q.copy()
    frozen[:, 6] = 0.1
    qd7, qdd7 = qd.copy(), qdd.copy()
    qd7[:, 6] = qdd7[:, 6] = 0.0
    with pytest.raises(IdentificationError, match=r"joint\(s\) 7 never move.*Izz7.*Fc7"):
        ols(robot, frozen, qd7, qdd7, tau, base=base)
    few = np.tile(np.arange(5), 20) * 100                      # 5 distinct states repeated: rank ≤ 35 < 57
    with pytest.raises(IdentificationError, match="rank-deficient data: cond"):
        ols(robot, q[few], qd[few], qdd[few], tau[few], base=base)


def test_model_file_round_trip_and_backbone_system(tmp_path, robot, base, prior, data):
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from proprio.identification.model_io import load_model, save_model
    from proprio.systems.rbd_backbone import AddRbdBackbone

    model = identify(prior, *data, method="ols", base=base, offsets=True)
    path = save_model(model, tmp_path / "m.npz")
    back = load_model(path)
    np.testing.assert_array_equal(back.phi_b, model.phi_b)
    assert back.names == model.names and back.names[-1] == "offset7"
    assert back.training_digest == model.training_digest and len(back.training_digest) == 64
    q, qd, qdd, tau = data
    builder = DiagramBuilder()
    rbd = AddRbdBackbone(builder, path)
    for name, value in (("q", q[10]), ("qd", qd[10]), ("qdd", qdd[10])):
        src = builder.AddSystem(ConstantVectorSource(value))
        builder.Connect(src.get_output_port(), rbd.GetInputPort(name))
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    out = rbd.GetOutputPort("tau_rbd").Eval(rbd.GetMyContextFromRoot(ctx))
    np.testing.assert_allclose(out, tau[10], atol=1e-7)


def test_excitation_optimiser_improves_cond_and_respects_constraints(robot, base):
    import math

    from proprio.identification.excitation import (
        _CondCost, check_collisions, condition_number, load_excitation_config, optimise_excitation,
        protocol_trajectory)

    cfg = load_excitation_config({"optimisation": {"starts": 1, "max_iterations": 4, "cost_samples": 30,
                                                   "constraint_samples": 200}})
    result = optimise_excitation(robot, cfg, base)
    traj = result.trajectory
    start = traj.evaluate(np.zeros(1))
    assert all(np.abs(s).max() < 1e-8 for s in start)                      # eq. 4.14: rest at q = 0
    q, qd, _ = traj.evaluate(np.linspace(0, traj.period, 2000))
    margin = math.radians(2.0)
    assert np.all(q >= robot.lower + margin - 1e-3) and np.all(q <= robot.upper - margin + 1e-3)
    assert np.all(np.abs(qd) <= robot.velocity_limits + 1e-3)
    assert np.isfinite(result.cond) and result.cond < 1e4
    t_cost = np.linspace(0, traj.period, 30, endpoint=False)
    assert condition_number(robot, base, *traj.evaluate(t_cost)) == pytest.approx(result.cond, rel=1e-9)
    # the analytic cond gradient matches central differences
    cost = _CondCost(robot, base, np.linspace(0, 20, 30, endpoint=False), 5, 0.1 * np.pi)
    x = np.random.default_rng(0).uniform(-0.3, 0.3, 70)
    _, grad = cost.value_and_gradient(x)
    e = np.zeros(70)
    e[17] = 1e-6
    fd = (cost.value_and_gradient(x + e)[0] - cost.value_and_gradient(x - e)[0]) / 2e-6
    assert grad[17] == pytest.approx(fd, rel=1e-4)
    assert check_collisions(robot, np.zeros((2, 7))) == []
    t, qp, qdp, _ = protocol_trajectory(traj, [1.0, 0.5], 50.0)
    assert t[-1] == pytest.approx(3 * traj.period, abs=0.05)
    assert np.max(np.abs(np.diff(qp, axis=0))) < 0.1                     # continuous across the joins


def test_real_lwr_identification_beats_flobaroid(lwr_dir, tmp_path, capsys):
    """Train on files 2+3, validate on 1, 500 samples trimmed at both ends (FloBaRoID's startOffset)."""
    from proprio.cli import main
    from proprio.identification.model_io import load_model
    from proprio.recording import load_recording

    out = tmp_path / "lwr.npz"
    rc = main(["identify", "--robot", str(lwr_dir), "--train", str(lwr_dir / "measurements_2.npz"),
               str(lwr_dir / "measurements_3.npz"), "--validate", str(lwr_dir / "measurements_1.npz"),
               "--trim", "2.5", "--offsets", "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "validation" in printed
    head = printed[:printed.index("OLS on")]             # data quality of each file first: warnings only
    assert head.count("data quality of ") == 3 and head.count("tau_filtered") == 3 and "INFO" not in head
    assert head.count("  conditioning: 200 Hz") == 3 and "measurements_1.npz (validate)" in head
    assert printed.count("conditioning: ") == 3             # each file's line once: not again above the tables
    model = load_model(out)
    assert model.base.n_base == 57
    val = load_recording(lwr_dir / "measurements_1.npz").slice(500, -500)
    e = val.tau - model.torque(val.q, val.qd, val.qdd)
    rmse = np.sqrt(np.mean(e ** 2, axis=0))
    flobaroid = np.array([0.27, 0.22, 0.25, 0.18, 0.35, 0.21, 0.23])   # README: their parameters, our model
    assert np.all(rmse < 0.3), rmse
    assert np.mean(np.linalg.norm(e, axis=1)) < 0.72                    # FloBaRoID's reported validation figure
    assert rmse.mean() < flobaroid.mean() + 0.01


def test_identify_recordings(robot, prior, data):
    from proprio.identification.recordings import identify_recordings
    from proprio.recording import Recording

    q, qd, qdd, tau = data
    t = np.arange(q.shape[0]) * 0.01
    # what a robot logs: q and τ only; q̇, q̈ come from the conditioning path
    train = Recording(t=t[:1500], q=q[:1500], tau=tau[:1500])
    val = Recording(t=t[1500:], q=q[1500:], tau=tau[1500:])
    model, text = identify_recordings([train], [val], prior)
    assert "validation" in text and "mean ||e||_2" in text and "conditioning:" in text
    err = model.torque(q[1500:], qd[1500:], qdd[1500:]) - tau[1500:]     # scored against the exact motion
    rms = np.sqrt(np.mean(err ** 2, axis=0))
    assert np.all(rms < 5e-3), rms           # N·m; what is left: Coulomb sign flips a filtered sample off a reversal
