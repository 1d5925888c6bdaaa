"""The one signal-conditioning path (issue 12): jittered stamps, gaps, per-joint cutoffs, its own error estimate."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from proprio.conditioning import ConditioningConfig, condition, processing_torque_sigma, zero_phase_lowpass
from proprio.cutoff import auto_cutoff, noise_floor_dof, tau_white_level
from proprio.time_base import clock_stamps
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


def test_a_high_encoder_floor_keeps_the_motion_and_the_clock():
    """A 1 kHz clock with 0.1 ms receive-time jitter, 2 % lost samples, 10⁻⁴ rad of encoder noise and a motion whose
    q̈ is spread evenly over 0.2–4 Hz (issue 39): the floor drops only ≈ 9 % in variance on the clock (the jitter's
    q̇·δt is small beside this encoder), which is far beyond the floor estimate's chance margin, so `auto` takes the
    clock and measures the encoder's σ; and at the stamps as on the clock the cutoff keeps the motion. Before, the
    three-point Δ²q at the jittered stamps buried the motion in white noise at every frequency, the cutoff fell to its
    1 Hz floor and q̈ lost 83 % of its RMS."""
    rng = np.random.default_rng(7)
    lines = np.arange(0.2, 4.0, 0.05)                                      # Hz
    amp = 0.2 / (2 * np.pi * lines) ** 2                                   # rad: 0.2 rad/s² of q̈ per line
    phase = rng.uniform(0.0, 2 * np.pi, (3, lines.size))

    def motion(t):
        arg = 2 * np.pi * lines * t[:, None, None] + phase
        return (amp * np.sin(arg)).sum(-1), -(amp * (2 * np.pi * lines) ** 2 * np.sin(arg)).sum(-1)

    tick = np.arange(0.0, 20.0, 1e-3)
    tick = tick[rng.random(tick.size) > 0.02]
    stamps = tick + np.clip(rng.normal(0.0, 1e-4, tick.size), -3e-4, 3e-4)
    q = motion(tick)[0]
    rec = Recording(t=stamps, q=q + rng.normal(0.0, 1e-4, q.shape), tau=q)
    for base in ("auto", "stamps"):
        cs = condition(rec, ConditioningConfig(time_base=base))
        assert any("regular clock" in note for note in cs.notes) == (base == "auto")
        qdd = motion(cs.t + stamps[0] - tick[0])[1]
        err = np.sqrt(np.mean((cs.qdd - qdd)[2000:-2000] ** 2, axis=0))
        assert np.all(cs.cutoff_hz > 4.0), cs.cutoff_hz                    # above the motion's band
        assert np.all(err < 0.05 * np.sqrt(np.mean(qdd ** 2, axis=0))), err
    assert condition(rec).sigma_q == pytest.approx(np.full(3, 1e-4), rel=0.02)


def _fast_log(rate: float, seconds: float, seed: int = 0) -> tuple[np.ndarray, Recording]:
    """A drive log at ``rate``: the slow motion of :func:`_motion` plus a 2e-6 rad structural vibration of q at 180 Hz
    (what a 5 kHz motor encoder sees; below Nyquist at 0.4 × the rate), encoder noise, and τ = 2 q + white noise of
    0.05 N·m."""
    t = np.arange(int(rate * seconds)) / rate
    rng = np.random.default_rng(seed)
    q, _, _ = _motion(t)
    f_vib = min(180.0, 0.4 * rate)
    q_meas = q + 2e-6 * np.sin(2 * np.pi * f_vib * t)[:, None] + rng.normal(0.0, 1e-6, q.shape)
    return t, Recording(t=t, q=q_meas, tau=2.0 * q + rng.normal(0.0, 0.05, q.shape))


@pytest.mark.parametrize("rate", [100.0, 200.0, 1000.0, 5000.0])
def test_auto_cutoff_follows_the_arm_not_its_vibration_at_every_rate(rate):
    t, rec = _fast_log(rate, 12.0)
    cs = condition(rec, ConditioningConfig(tau_filter=False))
    assert np.all(cs.cutoff_hz <= 40.0) and np.all(cs.cutoff_hz >= 1.0)
    _, _, qdd = _motion(cs.t)
    inner = (cs.t > 1.0) & (cs.t < cs.t[-1] - 1.0)
    err = np.sqrt(np.mean((cs.qdd - qdd)[inner] ** 2, axis=0))
    assert np.all(err < 0.02 * np.sqrt(np.mean(qdd ** 2, axis=0)))      # q̈ within 2 % of its RMS
    assert np.all(cs.sigma_qdd < 0.1)                                   # and its error estimate is no alarm


def test_a_fast_log_is_decimated_to_its_motion_band_with_the_noise_density_kept():
    t, rec = _fast_log(5000.0, 12.0)
    full = condition(rec, ConditioningConfig(tau_filter=False))
    dec = condition(rec, ConditioningConfig(tau_filter=False, decimate=True))
    assert full.rate_hz == pytest.approx(5000.0) and dec.rate_hz == pytest.approx(5000.0 / 12)
    assert any("decimated ×12" in n for n in dec.notes)
    _, _, qdd = _motion(dec.t)
    inner = (dec.t > 1.0) & (dec.t < dec.t[-1] - 1.0)
    assert np.all(np.sqrt(np.mean((dec.qdd - qdd)[inner] ** 2, axis=0)) < 0.02 * np.sqrt(np.mean(qdd ** 2, axis=0)))
    # τ's white noise keeps its density: variance / 12 on the 417 Hz grid, and tau_gain says so
    noise = (dec.tau - 2.0 * _motion(dec.t)[0])[inner]
    np.testing.assert_allclose(dec.tau_gain, 1 / 12)
    np.testing.assert_allclose(noise.std(axis=0), 0.05 * np.sqrt(dec.tau_gain), rtol=0.15)
    np.testing.assert_allclose(dec.sigma_tau, 0.05, rtol=0.1)          # the raw τ's own white level
    np.testing.assert_allclose(dec.sigma_tau3, dec.sigma_tau, rtol=0.05)  # white: the same level from Δ³τ
    low = scipy.signal.lfilter(*scipy.signal.butter(2, 0.3), rec.tau - 2.0 * _motion(rec.t)[0], axis=0)
    assert np.all(tau_white_level(low, 3) < 0.8 * tau_white_level(low))    # a low-passed floor: smaller from Δ³τ


def test_decimation_keeps_the_gaps_flagged():
    t, rec = _fast_log(1000.0, 12.0)
    keep = (t < 5.0) | (t > 5.2)                                       # a 200 ms dropout
    rec = Recording(t=t[keep], q=rec.q[keep], tau=rec.tau[keep])
    cs = condition(rec, ConditioningConfig(tau_filter=False, decimate=True))
    assert cs.rate_hz == pytest.approx(500.0)
    inside = (cs.t > 5.0) & (cs.t < 5.2)
    assert inside.any() and not cs.valid[inside].any()
    reach = 3.0 / cs.cutoff_hz.min() + 0.01                               # the filters' reach, 3 cutoff periods
    assert cs.valid[(cs.t < 5.0 - reach) | (cs.t > 5.2 + reach)].all()


def test_the_processing_floor_ignores_the_models_own_coulomb_jump():
    from dataclasses import replace

    from proprio.description import load_robot
    from proprio.diagnosis.data import SimModel

    robot = load_robot("iiwa14_nominal")
    t = np.arange(1000) / 100.0
    q = 0.3 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.ones(robot.n)
    cs = condition(Recording(t=t, q=q + np.random.default_rng(0).normal(0, 1e-4, q.shape),
                             tau=np.zeros_like(q)), ConditioningConfig(tau_filter=False))
    plain = SimModel(robot)
    coulomb = SimModel(replace(robot, friction_viscous=(0.0,) * robot.n, friction_coulomb=(13.0,) * robot.n))
    a = processing_torque_sigma(plain.smooth_torque, [cs])
    b = processing_torque_sigma(coulomb.smooth_torque, [cs])
    np.testing.assert_allclose(a, b)
    assert np.all(b < 1.0)              # a q̇ error flipping sign(q̇) would add up to 2 × 13 N·m near reversals


def test_auto_velocity_takes_the_robots_qd_only_when_it_does_not_lag():
    t = np.arange(0.0, 12.0, 5e-3)
    q, qd, _ = _motion(t)
    q_meas = q + np.random.default_rng(2).normal(0.0, 1e-4, q.shape)          # a coarse encoder: d/dt q is noisy
    good = condition(Recording(t=t, q=q_meas, tau=q, qd=qd), ConditioningConfig(velocity="auto"))
    assert good.velocity_source.startswith("the robot's q̇")
    lagged = np.vstack([qd[:1]] * 3 + [qd[:-3]])                            # the robot's filter: 15 ms late
    late = condition(Recording(t=t, q=q_meas, tau=q, qd=lagged), ConditioningConfig(velocity="auto"))
    assert late.velocity_source.startswith("q (the robot's q̇ lags by 15 ms")
