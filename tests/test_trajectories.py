"""Time parameterisation, Drake trajectory/replay sources and trajectory files (systems/trajectories.py)."""
from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import VectorLogSink
from pydrake.trajectories import PiecewisePolynomial

from proprio.recording import Recording
from proprio.systems.trajectories import (AddReplaySource, AddTrajectorySource, Phase, TrajectoryFileError,
                                          check_limits, load_trajectory, replay_trajectory, sample_trajectory,
                                          save_trajectory, time_parameterize)


@pytest.fixture(scope="module")
def desc():
    from proprio.description import load_robot
    return load_robot("iiwa14_identified")


@pytest.fixture(scope="module")
def timed(desc):
    rng = np.random.default_rng(3)
    q0, q1 = np.zeros(7), rng.uniform(-1.0, 1.0, 7)
    s = np.arange(1500)[:, None]
    wiggle = np.deg2rad(2.0) * np.sin(2 * np.pi * s / 300 * rng.uniform(1, 4, 7) + rng.uniform(0, 6, 7))
    e = q1 + wiggle - wiggle[0]
    phases = [Phase(np.stack([q0, q1]), 0.8, 0.8, "reach"), Phase(e, 0.2, 0.9, "explore"),
              Phase(np.stack([e[-1], q0]), 0.7, 0.7, "reach")]
    return phases, time_parameterize(phases, desc)


def test_limits_respected_densely(desc, timed):
    phases, tp = timed
    lim = check_limits(tp.trajectory, desc, rate_hz=2000.0)
    assert lim["velocity"] <= 0.8 * 1.005          # the fastest phase asked for 80 % of the velocity limit
    assert lim["velocity"] >= 0.8 * 0.97           # ... and gets it (the limiting joint cruises there)
    assert lim["acceleration"] <= 0.9 * 1.01
    assert lim["position_excess_rad"] < 0


def test_each_phase_within_its_fractions(desc, timed):
    phases, tp = timed
    for k, ph in enumerate(phases):
        _, _, qd, qdd = sample_trajectory(tp.trajectory, 2000.0, tp.phase_times[k], tp.phase_times[k + 1])
        assert np.max(np.abs(qd) / desc.velocity_limits) <= ph.velocity_fraction * 1.01
        assert np.max(np.abs(qdd) / desc.acceleration_limits) <= ph.acceleration_fraction * 1.02


def test_passes_through_phase_ends_at_rest(timed):
    phases, tp = timed
    traj, d1 = tp.trajectory, tp.trajectory.MakeDerivative(1)
    for k, ph in enumerate(phases):
        np.testing.assert_allclose(traj.value(tp.phase_times[k + 1]).ravel(), ph.waypoints[-1], atol=1e-9)
        # at rest up to the spline's interpolation error (the knots sample a rest-to-rest motion)
        assert np.all(np.abs(d1.value(tp.phase_times[k + 1]).ravel()) < 2e-3)   # rad/s, vs limits ≈ 1.5 rad/s
    np.testing.assert_allclose(d1.value(0.0).ravel(), 0.0, atol=1e-12)
    np.testing.assert_allclose(d1.value(tp.duration).ravel(), 0.0, atol=1e-12)


def test_c2_continuity_at_every_break(timed):
    _, tp = timed
    traj = tp.trajectory
    breaks = np.asarray(traj.get_segment_times())[1:-1]
    eps = 1e-9
    for order, tol in ((0, 1e-8), (1, 1e-7), (2, 1e-5)):   # a smooth function moves by |derivative|·2ε
        d = traj.MakeDerivative(order) if order else traj
        jump = np.abs(d.vector_values(breaks + eps) - d.vector_values(breaks - eps)).max()
        assert jump < tol, (order, jump)


def test_reach_is_joint_wise_linear(timed):
    phases, tp = timed
    for k in (0, 2):
        w = phases[k].waypoints
        t = np.linspace(tp.phase_times[k], tp.phase_times[k + 1], 400)
        q = tp.trajectory.vector_values(t).T - w[0]
        u = (w[1] - w[0]) / np.linalg.norm(w[1] - w[0])
        off_line = q - np.outer(q @ u, u)
        assert np.abs(off_line).max() < 1e-5            # spline interpolation error, O(knot_dt⁴)


def test_explore_follows_waypoints(timed):
    phases, tp = timed
    t0, t1 = tp.phase_times[1], tp.phase_times[2]
    q = tp.trajectory.vector_values(np.linspace(t0, t1, 3000)).T
    w = phases[1].waypoints
    # every waypoint is met by the trajectory (nearest sample within the sample spacing's travel)
    d = np.min(np.linalg.norm(q[None, :, :] - w[::50, None, :], axis=2), axis=1)
    assert d.max() < np.deg2rad(0.2)


def test_bad_phases(desc):
    q = np.zeros((2, 7))
    q[1, 0] = 0.5
    with pytest.raises(ValueError, match="fractions"):
        time_parameterize([Phase(q, 0.0, 0.5)], desc)
    with pytest.raises(ValueError, match="differs from the previous"):
        time_parameterize([Phase(q, 0.5, 0.5), Phase(q, 0.5, 0.5)], desc)
    with pytest.raises(ValueError, match="does not move"):
        time_parameterize([Phase(np.zeros((2, 7)), 0.5, 0.5)], desc)
    with pytest.raises(ValueError, match="shape"):
        time_parameterize([Phase(np.zeros((2, 6)), 0.5, 0.5)], desc)


def test_sample_trajectory(timed):
    _, tp = timed
    t, q, qd, qdd = sample_trajectory(tp.trajectory, 1000.0)
    assert t[0] == 0.0 and np.allclose(np.diff(t), 0.001)
    assert q.shape == qd.shape == qdd.shape == (t.size, 7)
    # derivatives agree with finite differences of the positions
    np.testing.assert_allclose(np.gradient(q, t, axis=0)[5:-5], qd[5:-5], atol=2e-3)


def _log(builder, port, n):
    log = builder.AddSystem(VectorLogSink(n))
    builder.Connect(port, log.get_input_port())
    return log


def test_trajectory_source_ports(timed):
    _, tp = timed
    traj = tp.trajectory
    b = DiagramBuilder()
    src = AddTrajectorySource(b, traj)
    names = [src.get_output_port(i).get_name() for i in range(src.num_output_ports())]
    assert names == ["q", "qd", "qdd", "state"]
    diagram = b.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(0.0)
    ctx = sim.get_mutable_context()
    for t in (0.3, 2.0, 7.5):
        ctx.SetTime(t)
        q = src.GetOutputPort("q").Eval(src.GetMyContextFromRoot(ctx))
        qd = src.GetOutputPort("qd").Eval(src.GetMyContextFromRoot(ctx))
        qdd = src.GetOutputPort("qdd").Eval(src.GetMyContextFromRoot(ctx))
        state = src.GetOutputPort("state").Eval(src.GetMyContextFromRoot(ctx))
        np.testing.assert_allclose(q, traj.value(t).ravel(), atol=1e-12)
        np.testing.assert_allclose(qd, traj.MakeDerivative(1).value(t).ravel(), atol=1e-12)
        np.testing.assert_allclose(qdd, traj.MakeDerivative(2).value(t).ravel(), atol=1e-10)
        np.testing.assert_allclose(state, np.concatenate([q, qd]), atol=0)


def test_replay_source_reproduces_samples():
    t = np.linspace(0.0, 1.0, 201)
    q = np.column_stack([np.sin(2 * np.pi * t * (j + 1) / 4) for j in range(7)])
    rec = Recording(t=t, q=q, tau=np.zeros_like(q))
    for interp in ("first_order_hold", "cubic"):
        traj = replay_trajectory(rec, interp)
        np.testing.assert_allclose(traj.vector_values(t).T, q, atol=1e-12)
    b = DiagramBuilder()
    src = AddReplaySource(b, rec)
    log = _log(b, src.GetOutputPort("q"), 7)
    diagram = b.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(0.5)
    data = log.FindLog(sim.get_context())
    np.testing.assert_allclose(data.data()[:, -1], q[100], atol=1e-12)
    with pytest.raises(ValueError, match="interpolation"):
        replay_trajectory(rec, "spline")


def test_save_load_roundtrip(tmp_path, timed):
    _, tp = timed
    path = save_trajectory(tmp_path / "t.npz", tp.trajectory, tp.meta())
    traj, meta = load_trajectory(path)
    tt = np.linspace(0, tp.duration, 5001)
    for order in (0, 1, 2):
        a = traj.MakeDerivative(order) if order else traj
        b = tp.trajectory.MakeDerivative(order) if order else tp.trajectory
        np.testing.assert_allclose(a.vector_values(tt), b.vector_values(tt), atol=1e-9)
    assert meta["phase_kinds"] == ["reach", "explore", "reach"]
    with np.load(path, allow_pickle=False) as z:
        assert set(z.files) == {"breaks", "q", "qd", "meta"}
    assert not list(tmp_path.glob(".t.npz*"))              # atomic write leaves no temp file


def test_save_rejects_non_cubic(tmp_path):
    t = np.linspace(0, 1, 5)
    lag = PiecewisePolynomial.LagrangeInterpolatingPolynomial(t, np.sin(t)[None, :])   # one quartic segment
    with pytest.raises(ValueError, match="piecewise-cubic"):
        save_trajectory(tmp_path / "x.npz", lag)


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_trajectory(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    np.savez(bad, breaks=np.arange(3.0))
    with pytest.raises(TrajectoryFileError, match="missing"):
        load_trajectory(bad)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(TrajectoryFileError, match="cannot read"):
        load_trajectory(junk)
