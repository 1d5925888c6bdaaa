"""The twin's measurement chain inside its Diagram: the compiled block register, the laws taken piece by piece equal
the laws taken at once, the Diagram's Recording equals the laws applied to its motion, the Diagram's content, and
the random streams (one per purpose) with the statistics of the configured noise, losses and jitter."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.trajectories import PiecewisePolynomial

from proprio.diagrams.twin import build_twin_diagram, load_twin_config, simulate_twin
from proprio.effects import EncoderNoise
from proprio.effects.sensor_chain import PathEffects, PositionSensor, TorqueSensor
from proprio.random_streams import generator_from_state, generator_state, stream
from proprio.reversals import reversal_travel
from proprio.robot_log import LoggerConfig, RobotLogger, logged_steps
from proprio.signals import MotionSignals
from proprio.systems.blocks import AddBlockRegister

Q_A = np.array([0.1, 0.5, -0.2, -1.2, 0.3, 0.7, 0.2])


def wobble(seconds: float, seed: int = 0, knots: int = 12) -> PiecewisePolynomial:
    """A motion from t = 0 that reverses every joint a few times."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, seconds, knots)
    q = Q_A + rng.uniform(-0.2, 0.2, (knots, 7))
    q[0] = Q_A
    return PiecewisePolynomial.CubicShapePreserving(t, q.T, True)


def pieces(n: int, sizes=(1, 7, 250, 1000, 333)) -> list[slice]:
    """Consecutive slices of ``range(n)`` of the given sizes, cycled (1-sample pieces included)."""
    out, i, k = [], 0, 0
    while i < n:
        out.append(slice(i, min(n, i + sizes[k % len(sizes)])))
        i, k = out[-1].stop, k + 1
    return out


@pytest.fixture(scope="module")
def calibrated():
    return load_twin_config("iiwa14_twin")


@pytest.fixture(scope="module")
def motion():
    traj = wobble(6.0)
    t = np.arange(0.0, 6.0, 1e-3)
    return t, traj.vector_values(t).T, traj.MakeDerivative(1).vector_values(t).T, \
        traj.MakeDerivative(2).vector_values(t).T


@pytest.mark.parametrize("dt, levels, phase", [(1e-3, (2, 3, 4), 1.1), (1e-3, (10, 10), 1.0), (1e-4, (10, 3), 0.5)])
def test_block_register_holds_each_block_at_its_phase(dt, levels, phase):
    """The output ``block`` from the register's phase past a block's last step until the next chunk's is that block,
    oldest first, whatever the rounding of the levels' event times; ``recent`` holds level 0's samples. A level-1
    period that is an exact multiple of the step in doubles (10 × 1 ms) shares the step's instants (no extra stop
    of the Simulator); otherwise (10 × 0.1 ms) level 1 fires half a step after its chunk's last step."""
    builder = DiagramBuilder()
    from pydrake.systems.primitives import TrajectorySource
    ramp = builder.AddSystem(TrajectorySource(PiecewisePolynomial.FirstOrderHold([0.0, 1.0], [[0.0, 1.0 / dt],
                                                                                              [0.0, -1.0 / dt]])))
    reg = AddBlockRegister(builder, [2], dt, levels)
    builder.Connect(ramp.get_output_port(), reg.samples[0])
    diagram = builder.Build()
    sim = Simulator(diagram)
    B = reg.size
    assert B == math.prod(levels) and reg.phase == pytest.approx(phase)
    chunk = math.prod(levels[:-1])          # the last level's period [steps]: the block stays until then
    for b in range(5):
        for at in (phase + 0.05, phase - 0.05 + chunk):
            sim.AdvanceTo((b * B + B - 1 + at) * dt)
            def value(port):
                return port.Eval(port.get_system().GetMyContextFromRoot(sim.get_context()))
            block = value(reg.block).reshape(B, 2)
            steps = b * B + np.arange(B)
            np.testing.assert_allclose(block[:, 0], steps, atol=1e-9)
            np.testing.assert_allclose(block[:, 1], -steps, atol=1e-9)
            last = int(math.floor(b * B + B - 1 + at))      # the newest step level 0 holds
            np.testing.assert_allclose(value(reg.recent).reshape(levels[0], 2)[:, 0],
                                       np.arange(last - levels[0] + 1, last + 1), atol=1e-9)
    if levels == (10, 10):
        sim = Simulator(diagram)
        sim.AdvanceTo(2000.5 * dt)
        assert sim.get_num_steps_taken() == 2001          # a stop per step and the end: level 1 at the steps' instants


def test_reversal_travel_in_pieces_equals_the_whole_motion(motion):
    _, q, qd, _ = motion
    noisy = qd + np.random.default_rng(1).normal(0, 3e-3, qd.shape)       # reversals at piece boundaries too
    whole = reversal_travel(q, noisy)
    carry, parts = None, []
    for sl in pieces(q.shape[0]):
        rt = reversal_travel(q[sl], noisy[sl], 2e-3, carry)
        carry, parts = rt.end, parts + [rt]
    for field in ("r", "direction", "segment"):
        assert np.array_equal(getattr(whole, field), np.concatenate([getattr(p, field) for p in parts])), field
    assert min(len(s) for s in whole.starts) > 10


def test_torque_and_position_sensors_in_pieces_equal_the_whole_motion(calibrated, motion):
    t, q, qd, qdd = motion
    tau_j = 30.0 * np.sin(3.0 * t)[:, None] * np.linspace(1, 0.2, 7)
    sensor_effects = [e for e in calibrated.effects if e.place == "sensor" and not isinstance(e, EncoderNoise)]
    sensor = TorqueSensor(sensor_effects, 7, seed=5)
    whole, whole_parts, _ = sensor.measure(MotionSignals(t, q, qd, qdd), tau_j)
    assert {"hysteresis", "lost_motion", "ripple", "torque_noise"} <= set(whole_parts)
    carry, got, got_parts = None, [], []
    for sl in pieces(t.size):
        tau, parts, carry = sensor.measure(MotionSignals(t[sl], q[sl], qd[sl], qdd[sl]), tau_j[sl], carry)
        got.append(tau)
        got_parts.append(parts)
    np.testing.assert_allclose(np.concatenate(got), whole, rtol=0, atol=1e-12)
    for name, part in whole_parts.items():
        np.testing.assert_allclose(np.concatenate([p[name] for p in got_parts]), part, rtol=0, atol=1e-12)
    # the batch law of each effect (what identification and diagnosis call) is the same law
    s = MotionSignals(t, q, qd, qdd, tau_j)
    for eff in sensor.gauge:
        np.testing.assert_allclose(whole_parts[eff.name], eff.torque(s), rtol=0, atol=1e-12)

    encoder = PositionSensor(calibrated.effect("encoder_noise"), 7, seed=5)
    q_whole, _ = encoder.measure(q)
    carry, got = None, []
    for sl in pieces(t.size):
        q_meas, carry = encoder.measure(q[sl], carry)
        got.append(q_meas)
    assert np.array_equal(np.concatenate(got), q_whole)


def test_link_path_effects_in_pieces_equal_the_whole_motion(motion):
    """Pre-sliding friction (a Dahl law on the drive) carries its state like the gauge's hysteresis."""
    from proprio.effects import make_effects
    t, q, qd, qdd = motion
    (eff,) = make_effects({"presliding": {"level": [3.0] * 7, "presliding_travel_deg": [0.3] * 7}}, 7)
    path = PathEffects([eff], 7)
    whole = eff.torque(MotionSignals(t, q, qd, np.zeros_like(qd)))
    state, got = path.start(), []
    for sl in pieces(t.size):
        s = MotionSignals(t[sl], q[sl], qd[sl], np.zeros_like(qd[sl]))
        piece = path.begin(s, state)
        got.append(piece.torque(eff, s))
        state = piece.end()
    np.testing.assert_allclose(np.concatenate(got), whole, rtol=0, atol=1e-12)


@pytest.mark.parametrize("channels", [("q", "tau"), ("q", "tau", "qd")])
def test_robot_logger_in_pieces_equals_the_whole_run(channels):
    cfg = LoggerConfig(rate_hz=1000.0, channels=channels, qd_filter_hz=30.0 if "qd" in channels else None,
                       stamp_jitter_ms=0.1, dropout_prob=0.05, dropout_max_samples=4)
    n = 20_000
    t = np.arange(n) * 1e-3
    q = np.sin(np.outer(t, np.arange(1, 4)))
    logger = RobotLogger(cfg, 3, seed=11)
    whole, _ = logger.log(t, q, logger.start(), last=True)
    carry, keep, stamps, qd = logger.start(), [], [], []
    for sl in pieces(n, (1, 3, 1000, 17, 500)):
        piece, carry = logger.log(t[sl], q[sl], carry, last=sl.stop == n)
        keep.append(piece.keep + sl.start)
        stamps.append(piece.stamps)
        qd.append(piece.qd)
    assert np.array_equal(np.concatenate(keep), whole.keep)
    assert np.array_equal(np.concatenate(stamps), whole.stamps)
    if "qd" in channels:
        np.testing.assert_allclose(np.concatenate(qd), whole.qd, rtol=0, atol=1e-9)
    assert whole.keep[0] == 0 and whole.keep[-1] == n - 1 and whole.stamps[0] == 0.0
    runs = np.diff(whole.keep) - 1
    assert runs.max() == cfg.dropout_max_samples and np.all(np.diff(whole.stamps) > 0)


def test_logged_steps_keep_the_nearest_step_to_each_nominal_instant():
    """Block by block as for the whole run, and as the twin always kept them (the reference below)."""
    def reference(n_steps, time_step, rate_hz):
        if abs(rate_hz * time_step - 1.0) < 1e-9:
            return np.arange(n_steps)
        t_want = np.arange(0.0, n_steps * time_step, 1.0 / rate_hz)
        return np.unique(np.minimum(np.round(t_want / time_step).astype(int), n_steps - 1))

    for n_steps in (1, 2, 999, 1000, 1001, 20_001, 30_007):
        for rate in (1000.0, 500.0, 200.0, 150.0, 333.0, 100.0, 7.0):
            ref = reference(n_steps, 1e-3, rate)
            assert np.array_equal(logged_steps(0, n_steps, n_steps, 1e-3, rate), ref), (n_steps, rate)
            blocks = [logged_steps(lo, lo + 1000, n_steps, 1e-3, rate) for lo in range(0, n_steps, 1000)]
            assert np.array_equal(np.concatenate(blocks), ref), (n_steps, rate)


def test_random_streams_are_numbers_and_one_per_purpose():
    g = stream(3, "torque_noise")
    g.integers(1, 4, size=3)                               # leaves a buffered 32-bit half in the state
    v = generator_state(g)
    assert v.dtype == float and v.size == 10 and np.all(v == np.round(v))
    h = generator_from_state(v)
    assert np.array_equal(g.standard_normal(50), h.standard_normal(50))
    assert np.array_equal(g.integers(1, 9, 20), h.integers(1, 9, 20))
    assert not np.array_equal(stream(3, "torque_noise").random(5), stream(3, "encoder_noise").random(5))
    assert np.array_equal(stream(3, "torque_noise").random(5), stream(3, "torque_noise").random(5))


def test_twin_recording_is_the_laws_applied_to_its_motion(calibrated):
    """The Diagram's Recording (three blocks, the last one partial) equals the sensor and logger laws applied at once
    to the decimated true motion it logged — noise and jitter included (one stream per purpose)."""
    cfg = calibrated.with_logger(rate_hz=500.0, dropout_prob=0.0, stamp_jitter_ms=0.2)
    rec = simulate_twin(cfg, wobble(2.4, seed=3), progress=False)
    tr = rec.truth
    assert rec.n_samples == 1201 and rec.meta["samples_lost"] == 0
    t_run = tr["t_true"] - tr["t_true"][0]                         # the first logged step is the run's t = 0
    np.testing.assert_allclose(t_run, np.arange(1201) * 2e-3, atol=1e-12)
    s = MotionSignals(t_run + cfg.session_time_s, tr["q_true"], tr["qd"], tr["qdd"])
    sensor_effects = [e for e in cfg.effects if e.place == "sensor" and not isinstance(e, EncoderNoise)]
    tau, parts, _ = TorqueSensor(sensor_effects, 7, cfg.seed).measure(s, tr["tau_J_true"])
    np.testing.assert_allclose(rec.tau, tau, rtol=0, atol=1e-11)
    for name, part in parts.items():
        np.testing.assert_allclose(tr[f"tau_{name}"], part, rtol=0, atol=1e-11)
    q_meas, _ = PositionSensor(cfg.effect("encoder_noise"), 7, cfg.seed).measure(tr["q_true"])
    assert np.array_equal(rec.q, q_meas)
    logger = RobotLogger(cfg.logger, 7, cfg.seed)
    logged, _ = logger.log(t_run, q_meas, logger.start(), last=True)
    np.testing.assert_allclose(rec.t, logged.stamps, rtol=0, atol=1e-15)
    sigma = 2e-4
    jitter = rec.t - t_run + (rec.t[0] - t_run[0])
    assert 0.8 * sigma < np.std(jitter) < 1.2 * sigma


def test_twin_noise_losses_and_jitter_have_the_configured_statistics(calibrated):
    """The streams changed (one per purpose instead of one for the whole chain); what they draw keeps the
    configured statistics: torque and encoder noise σ, the share of lost samples, the stamps' σ."""
    cfg = calibrated.with_logger(dropout_prob=0.01, dropout_max_samples=3, stamp_jitter_ms=0.1)
    rec = simulate_twin(cfg, wobble(8.0, seed=4, knots=20), progress=False)
    tr = rec.truth
    std = cfg.effect("torque_noise").std
    assert np.all(np.abs(tr["tau_torque_noise"].std(axis=0) / std - 1.0) < 0.05)
    enc = cfg.effect("encoder_noise")
    q_err = rec.q - tr["q_true"]
    expected = np.sqrt(enc.std ** 2 + enc.resolution ** 2 / 12.0)
    assert np.all(np.abs(q_err.std(axis=0) / expected - 1.0) < 0.1)
    n_steps = 8001
    lost = rec.meta["samples_lost"] / n_steps
    assert 0.5 * 0.01 * 2.0 < lost < 1.5 * 0.01 * 2.0             # p·E[burst] = 0.01 · 2 (bursts of 1–3)
    jitter = (rec.t - tr["t_true"]) - np.median(rec.t - tr["t_true"])
    assert abs(np.std(jitter) / 1e-4 - 1.0) < 0.1 and np.max(np.abs(jitter)) < 3.2e-4


def test_twin_diagram_holds_the_chain_and_python_runs_at_block_rate(calibrated):
    twin = build_twin_diagram(calibrated, wobble(1.0))
    names = {s.get_name() for s in twin.diagram.GetSystems()}
    assert {"block_register_level0", "block_register_level1", "log_sampler", "transmission", "torque_sensor",
            "encoder", "robot_logger", "block_clock"} <= names
    dot = twin.diagram.GetGraphvizString(max_depth=1)
    assert all(k in dot for k in ("torque_sensor", "encoder", "robot_logger", "block_register"))
    python = [s for s in twin.diagram.GetSystems() if type(s).__module__.startswith("proprio.")
              and isinstance(s, LeafSystem)]
    def events(system) -> tuple[int, int]:
        """Discrete updates and publishes of ``system`` alone over 2.55 s (inputs fixed at 0)."""
        ctx = system.CreateDefaultContext()
        for k in range(system.num_input_ports()):
            system.get_input_port(k).FixValue(ctx, np.zeros(system.get_input_port(k).size()))
        sim = Simulator(system, ctx)
        sim.AdvanceTo(2.55)
        return sim.get_num_discrete_updates(), sim.get_num_publishes()

    # the chain's Python Systems: events only on the clock, an update per chunk of 100 steps (a copy), one per block
    # of 1 000 (the laws, once) and a publish per block
    chain = {"log_sampler", "transmission", "torque_sensor", "encoder", "robot_logger", "block_clock"}
    assert {s.get_name(): events(s) for s in python if s.get_name() in chain} == {
        **{k: (0, 0) for k in chain - {"block_clock"}}, "block_clock": (25 + 2, 2)}
    assert math.prod(twin.chain.register.levels) == 100 and twin.chain.block_steps == 1000
