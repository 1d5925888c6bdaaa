"""The online path: the causal conditioning stage, the estimation Diagram with it, and the streaming entry point
``proprio.online.OnlineEstimator`` (same numbers as the Diagram to 1e-10, as the batch laws to 1e-9; validation of what a robot hands over)."""
import numpy as np
import pytest
import torch

from proprio.causal_conditioning import causal_conditioning
from proprio.description import load_robot
from proprio.diagrams.estimation import (RigidBodyTorqueModel, build_estimation_diagram, estimate_rows,
                                         run_estimation_diagram, split_estimate)
from proprio.diagrams.hybrid_torque_model import HybridTorqueModel
from proprio.dynamics import inverse_dynamics
from proprio.learning.datasets import DataConfig
from proprio.learning.features import feature_matrix, rotational_displacement
from proprio.learning.models import HybridModel, ModelConfig
from proprio.online import OnlineEstimator, OnlineInputError
from proprio.payload import Payload, attach_payload

RATE = 1000.0
HOME = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])


@pytest.fixture(scope="module")
def desc():
    return load_robot("iiwa14_identified")


def _motion(desc, seconds=1.5, rate=RATE, mass=1.0, seed=0):
    """A 1 kg payload at the flange during smooth motion: τ_J = τ_rbd,payload + friction + noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    w = rng.uniform(0.5, 1.5, desc.n)
    q = HOME + 0.2 * np.sin(np.outer(t, w))
    qd, qdd = 0.2 * w * np.cos(np.outer(t, w)), -0.2 * w ** 2 * np.sin(np.outer(t, w))
    tau = inverse_dynamics(attach_payload(desc, Payload(mass)), q, qd, qdd) \
        + RigidBodyTorqueModel(desc).tau_int(q, qd, qdd) + rng.normal(0, 0.02, q.shape)
    return t, q, qd, qdd, tau


def _hybrid(desc, t, q, qd, qdd, tau):
    torch.manual_seed(0)
    net = HybridModel(ModelConfig(arch="lstm2_fcl", lstm_hidden=12, rate_hz=RATE))
    net.set_normalisation(feature_matrix(tau, q, qd, qdd, rotational_displacement(q)), 0.1 * tau)
    return HybridTorqueModel(RigidBodyTorqueModel(desc), net, DataConfig(), "lstm2_fcl")


def _diagram(model, design, t, q, tau, qd=None):
    sig = {"t": t, "q": q, "tau": tau, "time_step": 1.0 / RATE}
    if qd is not None:
        sig["qd"] = qd
    diagram, estimator, logger = build_estimation_diagram(model, sig, conditioning=design)
    return run_estimation_diagram(diagram, estimator, logger, t[-1], 1.0 / RATE)[:t.size]


def _causally_conditioned(design, q, tau, qd=None):
    """The conditioner's outputs over a recording, from its matrices (the design's recursion, test-side)."""
    n = q.shape[1]
    u = np.hstack([q, tau] if qd is None else [q, qd, tau])
    x, y = design.initial_state(u[0]), np.empty((u.shape[0], 4 * n))
    for k in range(u.shape[0]):
        y[k] = design.C @ x + design.D @ u[k]
        x = design.A @ x + design.B @ u[k]
    return {"q": y[:, :n], "qd": y[:, n:2 * n], "qdd": y[:, 2 * n:3 * n], "tau": y[:, 3 * n:],
            "time_step": design.time_step}


def test_the_batch_conditioner_is_the_recursion(desc):
    """:meth:`CausalConditioning.condition` (the compiled LTI kernel over a whole log) equals the design's recursion
    written out test-side, for a differentiated and a measured velocity."""
    t, q, qd, qdd, tau = _motion(desc, seconds=0.3)
    for velocity, measured in (("q", None), ("measured", qd)):
        design = causal_conditioning(RATE, np.linspace(8.0, 14.0, desc.n), desc.n, velocity)
        u = np.hstack([q, tau] if measured is None else [q, measured, tau])
        got, expected = design.condition(u), _causally_conditioned(design, q, tau, measured)
        for key in ("q", "qd", "qdd", "tau"):
            np.testing.assert_allclose(got[key], expected[key], rtol=0, atol=1e-10 * (1 + np.abs(expected[key]).max()))
    with pytest.raises(ValueError, match="u must be"):
        design.condition(u[:, :-1])


@pytest.mark.parametrize("kind", ["rbd", "hybrid_lstm2_fcl"])
def test_streaming_equals_the_diagram_on_a_drive_arm(kind):
    """A drive-torque arm (TX40: τ_int reads q̈ for the rotor inertia), alone or as a hybrid model's backbone: the
    streaming estimator takes the same per-sample law as the Diagram, to 1e-10."""
    tx = load_robot("staubli_tx40")
    model = backbone = RigidBodyTorqueModel(tx)
    t = np.arange(int(1.0 * RATE)) / RATE
    w = np.random.default_rng(2).uniform(0.5, 1.5, tx.n)
    home = 0.5 * (np.asarray(tx.lower) + np.asarray(tx.upper))
    q = home + 0.2 * np.sin(np.outer(t, w))
    qd, qdd = 0.2 * w * np.cos(np.outer(t, w)), -0.2 * w ** 2 * np.sin(np.outer(t, w))
    tau = inverse_dynamics(tx, q, qd, qdd) + backbone.tau_int(q, qd, qdd)
    if kind.startswith("hybrid"):
        torch.manual_seed(0)
        net = HybridModel(ModelConfig(arch="lstm2_fcl", lstm_hidden=12, rate_hz=RATE, n_joints=tx.n))
        net.set_normalisation(feature_matrix(tau, q, qd, qdd, rotational_displacement(q)), 0.1 * tau)
        model = HybridTorqueModel(backbone, net, DataConfig(), "lstm2_fcl")
    design = causal_conditioning(RATE, 10.0, tx.n, "q")
    expected = _diagram(model, design, t, q, tau)
    est = OnlineEstimator.from_model(model, conditioning=design)
    got = np.array([est.step(t[k], q[k], tau[k]).vector for k in range(t.size)])
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)


@pytest.mark.parametrize("kind", ["rbd", "rbd_measured_velocity", "hybrid_lstm2_fcl"])
def test_streaming_equals_the_diagram(desc, kind):
    """The streaming estimator and the Diagram with the causal conditioner give the same estimates to 1e-10 on every
    sample (both wrenches, manipulability, flags, both τ̂_ext), for the RBD and the hybrid LSTM-2-FCL model; for the
    RBD model the batch laws (:func:`estimate_rows`) on the causally conditioned signals give them to 1e-9."""
    t, q, qd, qdd, tau = _motion(desc)
    model = _hybrid(desc, t, q, qd, qdd, tau) if kind.startswith("hybrid") else RigidBodyTorqueModel(desc)
    velocity = "measured" if kind == "rbd_measured_velocity" else "q"
    design = causal_conditioning(RATE, np.linspace(8.0, 14.0, desc.n), desc.n, velocity)
    measured = qd if velocity == "measured" else None
    expected = _diagram(model, design, t, q, tau, measured)
    est = OnlineEstimator.from_model(model, conditioning=design)
    got = np.array([est.step(t[k], q[k], tau[k], None if measured is None else measured[k]).vector
                    for k in range(t.size)])
    assert got.shape == expected.shape == (t.size, 14 + 2 * desc.n)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)
    if kind.startswith("rbd"):
        # numpy's batched RNEA instead of Drake's plant per step: the same laws up to rounding, which Ṁq̇'s central
        # difference (step 1e-5 rad) amplifies to a few 1e-10 N in the momentum wrench
        batch = estimate_rows(model, design.condition(np.hstack([q, tau] if measured is None else [q, measured, tau])))
        np.testing.assert_allclose(batch, expected, rtol=0, atol=1e-9)   # the estimates are estimates: the payload's weight (the untrained net adds noise)
        for obs in ("jacobian", "momentum"):
            fz = split_estimate(got, desc.n)[f"{obs}.wrench"][t > 0.5, 2]
            assert abs(np.median(fz) + 9.81) < 1.0


def test_a_different_design_gives_different_numbers(desc):
    """The equality above is not vacuous: another cutoff changes the estimate by far more than 1e-10."""
    t, q, qd, qdd, tau = _motion(desc, seconds=0.5)
    model = RigidBodyTorqueModel(desc)
    expected = _diagram(model, causal_conditioning(RATE, 10.0, desc.n), t, q, tau)
    est = OnlineEstimator.from_model(model, rate_hz=RATE, cutoff_hz=12.0)
    got = np.array([est.step(t[k], q[k], tau[k]).vector for k in range(t.size)])
    assert np.abs(got - expected).max() > 1e-3


def test_causal_derivatives_of_a_steady_sine_follow_the_filter(desc):
    """q = A sin(ωt): after the transient, q̂, q̂̇, q̂̈ are A·Im(H(jω)·(jω)^k·e^{jωt}) with the analog 2nd-order
    Butterworth H (the bilinear map pre-warped at the cutoff leaves ≪ 1 % here), and the lag is ≈ √2/ω_c."""
    n, fc, f, amp = desc.n, 10.0, 1.0, 0.3
    design = causal_conditioning(RATE, fc, n)
    t = np.arange(0.0, 3.0, 1.0 / RATE)
    w, wc = 2 * np.pi * f, 2 * np.pi * fc
    q = amp * np.sin(w * t)
    u = np.zeros((t.size, 2 * n))
    u[:, 0] = q
    u[:, n] = 5.0 * np.sin(w * t)                  # τ gets the same filter
    x = design.initial_state(u[0])
    y = np.empty((t.size, 4 * n))
    for k in range(t.size):
        y[k] = design.C @ x + design.D @ u[k]
        x = design.A @ x + design.B @ u[k]
    h = wc ** 2 / (wc ** 2 - w ** 2 + 1j * np.sqrt(2) * wc * w)
    late = t > 1.0
    for k, col in enumerate((0, n, 2 * n)):
        exact = amp * np.imag(h * (1j * w) ** k * np.exp(1j * w * t))
        np.testing.assert_allclose(y[late, col], exact[late], atol=2e-3 * amp * w ** k)
    np.testing.assert_allclose(y[late, 3 * n], 5.0 * np.imag(h * np.exp(1j * w * t))[late], atol=1e-2)
    lag = -np.angle(h) / w
    assert lag == pytest.approx(design.group_delay_s[0], rel=0.05)
    # a constant input stays put from the first sample: steady-state start, derivatives 0
    x = design.initial_state(np.r_[HOME, np.ones(n)])
    np.testing.assert_allclose(design.C @ x + design.D @ np.r_[HOME, np.ones(n)],
                               np.r_[HOME, np.zeros(2 * n), np.ones(n)], atol=1e-9)


def test_bad_samples_are_rejected_naming_the_field(desc):
    t, q, qd, qdd, tau = _motion(desc, seconds=0.05)
    est = OnlineEstimator.from_model(RigidBodyTorqueModel(desc), rate_hz=RATE, cutoff_hz=10.0)
    ref = OnlineEstimator.from_model(RigidBodyTorqueModel(desc), rate_hz=RATE, cutoff_hz=10.0)
    for k in range(3):
        est.step(t[k], q[k], tau[k])
        ref.step(t[k], q[k], tau[k])
    k = 3
    bad_q = q[k].copy()
    bad_q[4] = np.nan
    cases = [((t[k], q[k][:6], tau[k]), "q: expected 7"),
             ((t[k], q[k], np.ones((2, 7))), "tau_J: expected 7"),
             ((t[k], bad_q, tau[k]), "q: non-finite value nan at joint 5"),
             ((t[k], q[k], np.full(7, np.inf)), "tau_J: non-finite"),
             ((t[k - 1], q[k], tau[k]), "t: time stamps must increase"),
             ((t[k] + 0.01, q[k], tau[k]), "t: step"),
             ((float("nan"), q[k], tau[k]), "t: non-finite"),
             ((t[k], q[k], tau[k], qd[k]), "qd: this estimator differentiates q")]
    for args, message in cases:
        with pytest.raises(OnlineInputError, match=message):
            est.step(*args)
    # a rejected sample leaves the state as it was
    np.testing.assert_array_equal(est.step(t[k], q[k], tau[k]).vector, ref.step(t[k], q[k], tau[k]).vector)
    measured = OnlineEstimator.from_model(RigidBodyTorqueModel(desc), rate_hz=RATE, cutoff_hz=10.0,
                                          velocity="measured")
    with pytest.raises(OnlineInputError, match="qd: this estimator filters the robot's own velocity"):
        measured.step(t[0], q[0], tau[0])
    with pytest.raises(ValueError, match="rate_hz"):
        OnlineEstimator.from_model(RigidBodyTorqueModel(desc))
    with pytest.raises(ValueError, match="Nyquist"):
        causal_conditioning(RATE, 600.0, desc.n)


def test_reset_restarts_from_the_next_sample(desc):
    t, q, qd, qdd, tau = _motion(desc, seconds=0.2)
    est = OnlineEstimator.from_model(RigidBodyTorqueModel(desc), rate_hz=RATE, cutoff_hz=10.0)
    first = [est.step(t[k], q[k], tau[k]).vector for k in range(50)]
    est.reset()
    again = [est.step(t[k], q[k], tau[k]).vector for k in range(50)]     # t restarts: allowed after reset()
    np.testing.assert_array_equal(np.array(first), np.array(again))


@pytest.mark.parametrize("coulomb_velocity", [0.0, 0.02])
def test_per_sample_interaction_torque_equals_the_vectorised_one(desc, coulomb_velocity):
    """The folded per-sample τ_int of the per-step Systems (friction, Coulomb law, offsets of an identified model)
    equals the model's vectorised τ_int."""
    model = RigidBodyTorqueModel(desc, coulomb_velocity, offset=tuple(np.linspace(-0.5, 0.9, desc.n)))
    qd = np.random.default_rng(3).normal(0, 0.05, (20, desc.n))
    step = model.tau_int_step()
    np.testing.assert_allclose(np.array([step(row, row) for row in qd]), model.tau_int(qd, qd, qd), rtol=0, atol=1e-13)


def test_per_sample_interaction_torque_of_a_drive_arm_reads_qdd():
    """A drive-torque arm (the TX40: rotor inertia on q̈, motor friction): the per-sample τ_int of the Systems and
    the streaming estimator equals the vectorised one, q̈ included."""
    model = RigidBodyTorqueModel(load_robot("staubli_tx40"))
    assert model.reads_qdd
    rng = np.random.default_rng(4)
    qd, qdd = rng.normal(0, 0.5, (20, 6)), rng.normal(0, 5.0, (20, 6))
    step = model.tau_int_step()
    per_sample = np.array([step(v, a) for v, a in zip(qd, qdd)])
    np.testing.assert_allclose(per_sample, model.tau_int(qd, qd, qdd), rtol=0, atol=1e-12)
    assert np.abs(per_sample - np.array([step(v, 0 * a) for v, a in zip(qd, qdd)])).max() > 1e-3   # q̈ matters
