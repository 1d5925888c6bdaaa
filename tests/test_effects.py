"""The joint-effect library: dissipation, hysteresis loop shape, lost-motion window, ripple frequency, regressors,
configuration errors."""
from __future__ import annotations

import math

import numpy as np
import pytest

from proprio.effects import (EFFECTS, EffectConfigError, Hysteresis, LostMotion, Ripple, ViscousCoulomb,
                             make_effects)
from proprio.reversals import reversal_travel
from proprio.signals import MotionSignals

N_J = 7


def triangle(amplitude_deg: float = 10.0, speed: float = 0.15, cycles: float = 2.0, rate: float = 1000.0,
             n: int = N_J) -> MotionSignals:
    """Joint-wise triangular motion ±amplitude around 0 at constant speed [rad/s] (Fig. 2.5 experiment)."""
    amp = math.radians(amplitude_deg)
    period = 4 * amp / speed
    t = np.arange(0.0, cycles * period, 1.0 / rate)
    phase = (t / period) % 1.0
    tri = amp * np.where(phase < 0.25, 4 * phase, np.where(phase < 0.75, 2 - 4 * phase, 4 * phase - 4))
    q = np.repeat(tri[:, None], n, axis=1)
    qd = np.gradient(q, t, axis=0)
    return MotionSignals(t=t, q=q, qd=qd, qdd=np.gradient(qd, t, axis=0))


def random_motion(seed: int = 0, n_s: int = 4000, n: int = N_J) -> MotionSignals:
    rng = np.random.default_rng(seed)
    t = np.arange(n_s) * 1e-3
    freqs = rng.uniform(0.2, 3.0, (3, n))
    amps = rng.uniform(0.01, 0.3, (3, n))
    q = np.sum(amps[:, None] * np.sin(2 * np.pi * freqs[:, None] * t[None, :, None]), axis=0)
    qd = np.gradient(q, t, axis=0) + rng.normal(0, 1e-3, q.shape)       # noisy velocities cross zero often
    return MotionSignals(t=t, q=q, qd=qd, qdd=np.gradient(qd, t, axis=0), tau=rng.normal(0, 20, q.shape))


@pytest.mark.parametrize("block", [
    {"viscous": [0.24, 0.37, 0.11, 0.1, 0.1, 0.12, 0.1], "coulomb": [0.32, 0.18, 0.07, 0.18, 0.03, 0.13, 0.09]},
])
def test_viscous_coulomb_never_injects_energy(block):
    s = random_motion()
    for name, blk in (("viscous_coulomb", block), ("stribeck", {"static": 0.4, "stribeck_velocity": 0.05})):
        tau = EFFECTS[name].from_config(blk, N_J).torque(s)
        power = tau * s.qd                                                  # dissipated power
        assert np.all(power >= 0.0), name
        assert power.sum() > 0.0


def test_hysteresis_loop_has_positive_area_and_saturates():
    s = triangle(cycles=2.0)
    hyst = Hysteresis.from_config({"saturation": 1.0, "saturation_travel_deg": 6.0}, N_J)
    tau = hyst.torque(s)[:, 0]
    q = s.q[:, 0]
    second = s.t >= s.t[-1] / 2                                          # a full steady cycle
    area = np.sum(0.5 * (tau[second][1:] + tau[second][:-1]) * np.diff(q[second]))   # ∮ τ dq (dissipated)
    assert area > 0.5 * (2 * 1.0) * math.radians(20)                    # dissipates most of the 2·τ_sat·Δq box
    # slope after a reversal vs. after 6° of travel
    rt = reversal_travel(s.q, s.qd)
    r = np.abs(rt.r[:, 0])
    rising = (rt.direction[:, 0] > 0) & second
    dtau = np.gradient(tau, q)
    slope0 = np.median(np.abs(dtau[rising & (r < math.radians(0.2))]))
    slope6 = np.max(np.abs(dtau[rising & (r > math.radians(6.0)) & (r < math.radians(19.0))]))
    assert slope6 < 0.1 * slope0
    assert np.max(np.abs(tau)) <= 1.0 + 1e-12
    # continuous at reversals (no jump larger than a few steps of the steepest slope)
    assert np.max(np.abs(np.diff(tau))) < 5 * slope0 * 0.15 * 1e-3


def test_hysteresis_load_gain_scales_with_tau_and_needs_it():
    s = triangle(cycles=1.0)
    hyst = Hysteresis.from_config({"saturation": 0.5, "load_gain": 0.01}, N_J)
    with pytest.raises(ValueError, match="tau"):
        hyst.torque(s)
    light = hyst.torque(s.with_tau(np.full_like(s.q, 10.0)))
    heavy = hyst.torque(s.with_tau(np.full_like(s.q, 80.0)))
    assert np.max(np.abs(heavy)) > 2.0 * np.max(np.abs(light))


def test_reversal_travel_ignores_noise_below_deadband_and_resets_at_reversals():
    s = triangle(cycles=1.0)
    noisy_qd = s.qd + np.random.default_rng(1).uniform(-1e-3, 1e-3, s.qd.shape) * (np.abs(s.qd) < 1e-6)
    rt = reversal_travel(s.q, noisy_qd, reversal_velocity=2e-3)
    assert len(rt.starts[0]) == 3                                          # two reversals (+10°, −10°) in one cycle
    assert np.max(np.abs(rt.r[:, 0])) == pytest.approx(math.radians(20), abs=math.radians(0.05))


def test_lost_motion_window_is_about_one_degree():
    """With lost motion equal to the Coulomb level, τ barely changes for ≈1° after a reversal, then flips fully."""
    s = triangle(cycles=1.5)
    fc = 0.3
    fric = ViscousCoulomb.from_config({"coulomb": fc, "smooth_velocity": 0.005}, N_J)
    lost = LostMotion.from_config({"amplitude": fc, "window_deg": 1.0}, N_J)
    tau = (fric.torque(s) + lost.torque(s))[:, 0]
    rt = reversal_travel(s.q, s.qd)
    r = np.abs(rt.r[:, 0])
    after_first = rt.segment[:, 0] >= 1
    i_rev = np.argmax(after_first)
    before = tau[i_rev - 50]                                             # steady value before the reversal
    change = np.abs(tau - before)
    window = after_first & (rt.segment[:, 0] == 1)
    assert np.max(change[window & (r < math.radians(0.5))]) < 0.05 * 2 * fc
    assert np.min(change[window & (r > math.radians(1.5)) & (r < math.radians(15))]) > 0.95 * 2 * fc
    half = np.min(r[window & (change > fc)])                             # travel at which half the flip is back
    assert math.radians(0.8) < half < math.radians(1.2)


def test_ripple_frequency_tracks_speed():
    rip = Ripple.from_config({"amplitude": 0.2, "gear_ratio": 160, "harmonic": 2}, 1)
    for speed in (0.05, 0.15, 0.4):
        t = np.arange(0, 4.0, 1e-3)
        q = (speed * t)[:, None]
        s = MotionSignals(t, q, np.full_like(q, speed), np.zeros_like(q))
        tau = rip.torque(s)[:, 0]
        spec = np.abs(np.fft.rfft(tau * np.hanning(t.size)))
        f = np.fft.rfftfreq(t.size, 1e-3)
        expected = 2 * 160 * speed / (2 * np.pi)
        assert abs(f[np.argmax(spec)] - expected) < 0.5


@pytest.mark.parametrize("name,block", [
    ("viscous_coulomb", {"viscous": 0.2, "coulomb": [0.1, 0.2, 0.3, 0.1, 0.05, 0.1, 0.1]}),
    ("ripple", {"amplitude": 0.3, "phase_deg": 40.0}),
    ("sensor_offset_gain", {"offset": [0.1, -0.9, 0.3, 0.5, -0.2, 0.4, 0.7], "gain": 0.01}),
])
def test_regressor_reproduces_torque(name, block):
    s = random_motion()
    eff = EFFECTS[name].from_config(block, N_J)
    assert eff.linear
    reg = eff.regressor(s)
    assert reg.shape == (s.q.shape[0], N_J, eff.vector().size)
    np.testing.assert_allclose(np.einsum("tnp,p->tn", reg, eff.vector()), eff.torque(s), atol=1e-12)
    lo, hi = eff.bounds()
    assert np.all(lo <= eff.vector()) and np.all(eff.vector() <= hi)
    np.testing.assert_allclose(eff.with_vector(eff.vector()).torque(s), eff.torque(s), atol=1e-12)


def test_nonlinear_effects_refuse_regressor_and_roundtrip_vector():
    s = random_motion()
    hyst = Hysteresis.from_config({"saturation": 0.8}, N_J)
    with pytest.raises(NotImplementedError):
        hyst.regressor(s)
    theta = hyst.vector() * 1.5
    assert np.allclose(hyst.with_vector(theta).vector(), theta)


def test_noise_is_seeded_and_encoder_quantises():
    s = random_motion()
    noise = EFFECTS["torque_noise"].from_config({"std": 0.5}, N_J)
    a = noise.torque(s, np.random.default_rng(3))
    b = noise.torque(s, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert abs(a.std() - 0.5) < 0.02
    with pytest.raises(ValueError, match="rng"):
        noise.torque(s)
    enc = EFFECTS["encoder_noise"].from_config({"std_deg": 0.0, "resolution_deg": 0.01}, N_J)
    qm = enc.measure(s.q, np.random.default_rng(0))
    steps = qm / math.radians(0.01)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    assert np.max(np.abs(qm - s.q)) <= math.radians(0.005) + 1e-12


def test_config_errors_name_the_problem():
    with pytest.raises(EffectConfigError, match="effects: hysterisis: unknown joint effect 'hysterisis'; did you "
                                                 "mean 'hysteresis'"):
        make_effects({"hysterisis": {"saturation": 1.0}}, N_J)
    with pytest.raises(EffectConfigError, match=r"elasticity.stiffness = -5"):
        make_effects({"elasticity": {"stiffness": -5.0}}, N_J)
    with pytest.raises(EffectConfigError, match=r"viscous_coulomb.coulomb: expected one number or a list of 7 numbers"):
        make_effects({"viscous_coulomb": {"coulomb": [0.1, 0.2]}}, N_J)
    with pytest.raises(EffectConfigError, match="ripple.amplitud: unknown key; did you mean 'amplitude'"):
        make_effects({"ripple": {"amplitud": 0.1}}, N_J)
    effects = make_effects({"torque_noise": {"std": 0.1}, "viscous_coulomb": {"coulomb": 0.1}}, N_J)
    assert [e.name for e in effects] == ["viscous_coulomb", "torque_noise"]
    assert all(e.place in ("motor", "link", "sensor") for e in effects)


def test_lost_motion_is_zero_before_a_joint_first_moves():
    s = triangle(cycles=1.0)
    pad = 200
    q = np.vstack([np.zeros((pad, N_J)), s.q])
    qd = np.vstack([np.zeros((pad, N_J)), s.qd])
    t = np.arange(q.shape[0]) * 1e-3
    rest = MotionSignals(t, q, qd, np.zeros_like(q))
    tau = LostMotion.from_config({"amplitude": 0.3}, N_J).torque(rest)
    np.testing.assert_array_equal(tau[:pad], 0.0)
    assert np.min(tau[pad + 5:pad + 50, 0]) < -0.29                     # then holds −A while the flip is lost


def test_the_reversal_travel_is_computed_once_per_motion_and_deadband():
    """A fit evaluates hysteresis and lost motion many times on the same signals: their reversal travel is memoised
    per motion and deadband (``MotionSignals.derived``), equal to :func:`reversal_travel` of the same inputs, shared by
    ``with_tau`` and recomputed for another deadband or another motion."""
    from proprio.effects.base import motion_reversal_travel

    t = np.linspace(0.0, 4.0, 801)
    q = np.column_stack([0.3 * np.sin(2 * t), 0.2 * np.sin(3 * t + 1.0)])
    s = MotionSignals(t, q, np.gradient(q, t, axis=0), np.zeros_like(q))
    hyst = Hysteresis(2, saturation=np.array([0.5, 0.2]))
    first = hyst.torque(s)
    rt = motion_reversal_travel(s, hyst.reversal_velocity)
    assert len(s.derived) == 1 and motion_reversal_travel(s.with_tau(first), hyst.reversal_velocity) is rt
    ref = reversal_travel(s.q, s.qd, hyst.reversal_velocity)
    assert np.array_equal(rt.r, ref.r) and np.array_equal(rt.segment, ref.segment)
    np.testing.assert_array_equal(hyst.torque(s), first)
    LostMotion(2, amplitude=np.array([0.1, 0.1]), reversal_velocity=np.array([2e-3, 0.5])).torque(s)
    assert len(s.derived) == 2                                        # another deadband: its own travel
    moved = MotionSignals(t, q + 0.1 * t[:, None], s.qd + 0.1, s.qdd)
    assert not np.array_equal(Hysteresis(2, saturation=np.array([0.5, 0.2])).torque(moved), first)
