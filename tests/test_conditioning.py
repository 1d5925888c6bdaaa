"""The one signal-conditioning path (issue 12): jittered stamps, gaps, per-joint cutoffs, its own error estimate."""
from __future__ import annotations

import numpy as np
import pytest

from proprio.conditioning import ConditioningConfig, condition, processing_torque_sigma, zero_phase_lowpass
from proprio.recording import Recording, RecordingError

AMP = np.array([0.4, 0.3, 0.5])
FREQ = np.array([0.3, 0.7, 1.1])           # Hz
ENC_STD = np.radians(0.0005)


def _motion(t: np.ndarray):
    w = 2 * np.pi * FREQ
    q = AMP * np.sin(w * t[:, None])
    return q, AMP * w * np.cos(w * t[:, None]), -AMP * w ** 2 * np.sin(w * t[:, None])


def _jittered_stamps(seconds: float, seed: int) -> np.ndarray:
    """FRI-like stamps: ~1 ms steps between 0.7 and 8.5 ms, ~2 % of them longer than 1.5 ms."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 1000)
    dt = rng.uniform(0.7e-3, 1.3e-3, n)
    late = rng.random(n) < 0.02
    dt[late] = rng.uniform(1.6e-3, 8.5e-3, late.sum())
    return np.concatenate([[0.0], np.cumsum(dt)])


def _recording(t: np.ndarray, seed: int = 0) -> Recording:
    rng = np.random.default_rng(seed)
    q, _, _ = _motion(t)
    return Recording(t=t, q=q + rng.normal(0.0, ENC_STD, q.shape), tau=2.0 * q + rng.normal(0.0, 0.05, q.shape))


def test_jittered_log_gives_accurate_derivatives_and_an_honest_error_estimate():
    t = _jittered_stamps(20.0, seed=1)
    cs = condition(_recording(t))
    assert cs.rate_hz == pytest.approx(1000.0, rel=0.05)
    assert np.allclose(np.diff(cs.t), 1.0 / cs.rate_hz)              # a uniform grid
    assert any("resampled" in note for note in cs.notes)
    _, qd, qdd = _motion(cs.t)
    sl = slice(2000, -2000)                                          # away from the filter edges
    err_qd = np.sqrt(np.mean((cs.qd - qd)[sl] ** 2, axis=0))
    err_qdd = np.sqrt(np.mean((cs.qdd - qdd)[sl] ** 2, axis=0))
    qdd_rms = np.sqrt(np.mean(qdd ** 2, axis=0))
    assert np.all(err_qdd < 0.05 * qdd_rms), (err_qdd, qdd_rms)
    raw = np.gradient(np.gradient(_recording(t).q, t, axis=0), t, axis=0) - _motion(t)[2]
    assert np.all(np.sqrt(np.mean(raw[2000:-2000] ** 2, axis=0)) > 100 * err_qdd)   # plain np.gradient's error
    # the path's own error estimate is of the right size (within a factor of 5 either way)
    assert np.all(cs.sigma_qdd < 5 * err_qdd) and np.all(cs.sigma_qdd > err_qdd / 5), (cs.sigma_qdd, err_qdd)
    assert np.all(cs.sigma_qd < 5 * err_qd + 1e-4)
    assert cs.sigma_q == pytest.approx(np.full(3, ENC_STD), rel=0.3)
    assert "cutoff" in cs.describe() and "auto" in cs.describe()


def test_gaps_are_flagged_and_dropouts_interpolated():
    t = np.arange(0.0, 10.0, 1e-3)
    t = np.concatenate([t[:4000], t[4050:]])                          # a 50 ms dropout
    t = t + np.random.default_rng(2).uniform(-2e-4, 2e-4, t.size) * (np.arange(t.size) % 2)   # and jitter
    cs = condition(_recording(t))
    assert 45 <= int((~cs.valid).sum()) <= 52
    bad = np.flatnonzero(~cs.valid)
    assert cs.t[bad[0]] == pytest.approx(4.0, abs=2e-3)
    assert any("gap" in note for note in cs.notes)


def test_tau_gets_the_same_lowpass_and_uniform_logs_are_not_resampled():
    t = np.arange(0.0, 8.0, 1e-3)
    rec = _recording(t)
    cs = condition(rec, ConditioningConfig(cutoff_hz=(10.0, 12.0, 15.0)))
    assert not cs.notes and np.array_equal(cs.t, t)
    np.testing.assert_allclose(cs.tau, zero_phase_lowpass(rec.tau, 1000.0, [10.0, 12.0, 15.0]), atol=1e-12)
    raw = condition(rec, ConditioningConfig(cutoff_hz=10.0, tau_filter=False))
    np.testing.assert_array_equal(raw.tau, rec.tau)
    assert np.all(cs.tau_gain < 0.1) and np.all(raw.tau_gain == 1.0)


def test_robot_velocity_is_used_when_given_and_never_its_acceleration():
    t = np.arange(0.0, 8.0, 5e-3)
    q, qd, qdd = _motion(t)
    rec = Recording(t=t, q=q, tau=q, qd=qd, qdd=np.zeros_like(q))    # a nonsense q̈ must be ignored
    cs = condition(rec, ConditioningConfig(cutoff_hz=8.0, velocity="auto"))
    assert "robot" in cs.velocity_source
    assert np.sqrt(np.mean((cs.qdd - qdd)[200:-200] ** 2)) < 0.01
    with pytest.raises(RecordingError, match="velocity"):
        condition(Recording(t=t, q=q, tau=q), ConditioningConfig(velocity="measured"))


def test_bad_settings_and_short_logs_name_the_problem():
    with pytest.raises(ValueError, match="cutoff_hz"):
        ConditioningConfig.from_dict({"cutoff_hz": "fast"})
    with pytest.raises(ValueError, match="unknown key"):
        ConditioningConfig.from_dict({"cutof_hz": 5})
    t = np.arange(0.0, 0.1, 1e-3)
    with pytest.raises(RecordingError, match="shorter than one period"):
        condition(_recording(t), ConditioningConfig(cutoff_hz=2.0))
    with pytest.raises(RecordingError, match="Nyquist"):
        condition(_recording(np.arange(0.0, 2.0, 1e-2)), ConditioningConfig(cutoff_hz=60.0))


def test_processing_torque_sigma_scales_with_the_derivative_errors():
    cs = condition(_recording(np.arange(0.0, 10.0, 1e-3)))
    inertia = np.array([2.0, 1.0, 0.5])
    sigma = processing_torque_sigma(lambda q, qd, qdd: inertia * qdd, [cs], seed=3)
    np.testing.assert_allclose(sigma, inertia * cs.sigma_qdd, rtol=0.15)
