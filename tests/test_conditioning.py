"""The one signal-conditioning path (issue 12): jittered stamps, gaps, per-joint cutoffs, its own error estimate."""
from __future__ import annotations

import numpy as np
import pytest

from proprio.conditioning import (ConditioningConfig, auto_cutoff, clock_stamps, condition, noise_floor_dof,
                                 processing_torque_sigma, zero_phase_lowpass)
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


def test_noise_floor_degrees_of_freedom_match_the_spread_of_the_estimate():
    # D·σ̂²/σ² ~ χ²_D: over many white-noise records the relative variance of σ̂² is 2/D
    rng = np.random.default_rng(4)
    for n in (1500, 4000):
        q = rng.normal(0.0, ENC_STD, (n, 300))
        ratio = (auto_cutoff(q, 200.0)[1] / ENC_STD) ** 2
        d = noise_floor_dof(n)
        assert 0.35 * n < d < 0.55 * n                                # ≈ 2 per independent frequency of the band
        assert 2.0 / np.var(ratio) == pytest.approx(d, rel=0.2)
        assert np.mean(ratio) == pytest.approx(1.0, abs=0.02)          # the floor is unbiased within 2 %
    cs = condition(_recording(np.arange(0.0, 10.0, 1e-3)))
    assert cs.sigma_q_dof == noise_floor_dof(cs.n_samples) and cs.slice(0, 100).sigma_q_dof == cs.sigma_q_dof


def test_gaps_are_flagged_and_dropouts_interpolated():
    t = np.arange(0.0, 10.0, 1e-3)
    t = np.concatenate([t[:4000], t[4050:]])                          # a 50 ms dropout
    t = t + np.random.default_rng(2).uniform(-2e-4, 2e-4, t.size) * (np.arange(t.size) % 2)   # and jitter
    cs = condition(_recording(t))
    assert 45 <= int(cs.gap.sum()) <= 52
    bad = np.flatnonzero(cs.gap)
    assert cs.t[bad[0]] == pytest.approx(4.0, abs=2e-3)
    assert any("gap" in note for note in cs.notes)
    assert cs.rate_hz / cs.cutoff_hz.min() > bad.size      # shorter than a cutoff period: the spline bridges it
    assert np.array_equal(~cs.valid, cs.gap)
    # across a 2 s hole the fill is guesswork, and the zero-phase filters spread it over 3 cutoff periods each side
    t2 = np.concatenate([t[:3000], t[5000:]])
    cs = condition(_recording(t2), ConditioningConfig(cutoff_hz=10.0))
    bad, invalid = np.flatnonzero(cs.gap), np.flatnonzero(~cs.valid)
    reach = int(np.ceil(3.0 * cs.rate_hz / 10.0))
    assert cs.t[bad[0]] == pytest.approx(3.0, abs=2e-3)
    assert bad.size == pytest.approx(1e3 * (t2[3000] - t2[2999]), abs=2)
    assert invalid[0] == bad[0] - reach and invalid[-1] == bad[-1] + reach and invalid.size == bad.size + 2 * reach


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


def test_receive_time_jitter_is_put_back_on_the_clock_and_irregular_sampling_is_not():
    """Samples taken on a regular 1 kHz clock but stamped with ±0.3 ms receive-time jitter (and lost packets): `auto`
    places them on the clock, which cuts the q̈ error severalfold; samples really taken at irregular instants
    (6/7 ms steps) keep their stamps."""
    rng = np.random.default_rng(4)
    tick = np.arange(0.0, 20.0, 1e-3)
    tick = tick[rng.random(tick.size) > 0.02]                               # 2 % lost
    q, _, _ = _motion(tick)
    stamps = tick + np.clip(rng.normal(0.0, 1e-4, tick.size), -3e-4, 3e-4)
    rec = Recording(t=stamps, q=q + rng.normal(0.0, ENC_STD, q.shape), tau=q)
    errs = {}
    for base in ("auto", "stamps"):
        cs = condition(rec, ConditioningConfig(time_base=base))
        qdd = _motion(cs.t + stamps[0] - tick[0])[2]                           # the grid starts at the first stamp
        errs[base] = np.sqrt(np.mean((cs.qdd - qdd)[2000:-2000] ** 2))
        if base == "auto":
            assert any("regular clock" in note for note in cs.notes)
    assert errs["auto"] < errs["stamps"] / 3, errs
    t67 = np.cumsum(np.tile([0.006, 0.007, 0.007], 1000))
    irregular = condition(_recording(t67))
    assert not any("clock" in note for note in irregular.notes)
    assert irregular.rate_hz == pytest.approx(1 / np.mean(np.diff(t67)), rel=1e-9)   # the mean step (6.67 ms)
    assert clock_stamps(np.array([0.0, 1.1e-3, 1.3e-3, 3.0e-3]), 1e-3) is None   # two stamps on one tick
    with pytest.raises(RecordingError, match="same tick"):
        condition(Recording(t=np.cumsum(np.tile([1e-3, 0.2e-3, 1.8e-3], 100)), q=np.zeros((300, 1)),
                            tau=np.zeros((300, 1))), ConditioningConfig(time_base="clock", cutoff_hz=20.0))
