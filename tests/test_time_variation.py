"""Time variation in the gap diagnosis: the time-varying effects, the session clock of the twin and of the
diagnosis, the time-dependence test (drift, warm-up, steps between sessions, and no false alarm on a static gap),
and the time-trend nuisance that keeps a drift out of the rigid-body candidate."""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest

from proprio.gap_benchmark.case_data import generate_case_data
from proprio.gap_benchmark.cases import SESSION_S, BenchmarkCase, make_cases, time_varying_cases
from proprio.diagnosis.candidates.registry import candidate_set
from proprio.diagnosis.data import (DIAGNOSIS_CONDITIONING, DiagnosisError, GapData, SimModel, condition_all, kept,
                                    session_time)
from proprio.diagnosis.fitting import fit_candidates, predict_candidates
from proprio.diagnosis.candidates.rigid_body import RigidBodyCandidate
from proprio.diagnosis.selection.time_variation import TimeTrendNuisance, time_variation
from proprio.effects import EFFECTS, FrictionWarmup, OffsetDrift
from proprio.signals import MotionSignals

N_J = 7
SHORT_S = 10.0          # s per recording: enough blocks for the test, fast enough for the suite


def _motion(t: np.ndarray, seed: int = 0) -> MotionSignals:
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.3, 1.5, N_J)
    q = 0.3 * np.sin(2 * np.pi * f * t[:, None])
    qd = 0.3 * 2 * np.pi * f * np.cos(2 * np.pi * f * t[:, None])
    return MotionSignals(t, q, qd, -(2 * np.pi * f) ** 2 * q)


def test_time_varying_effects_follow_the_session_clock():
    t = np.linspace(0.0, 300.0, 601)
    drift = OffsetDrift(N_J, offset=0.1, drift=np.linspace(-0.5, 0.5, N_J), time_constant=60.0)
    tau = drift.torque(_motion(t))
    np.testing.assert_allclose(tau[0], 0.1)
    np.testing.assert_allclose(tau[-1], 0.1 + drift.drift * (1 - np.exp(-5.0)), atol=1e-12)
    # one time constant after the start, 63 % of the change has happened
    i = np.argmin(np.abs(t - 60.0))
    np.testing.assert_allclose(tau[i] - 0.1, drift.drift * (1 - np.exp(-1.0)), atol=1e-12)
    assert EFFECTS["offset_drift"] is OffsetDrift and EFFECTS["friction_warmup"] is FrictionWarmup
    assert OffsetDrift.time_varying and not EFFECTS["sensor_offset_gain"].time_varying
    np.testing.assert_allclose(drift.with_vector(drift.vector()).torque(_motion(t)), tau)


def test_friction_warmup_is_dissipative_and_fades():
    t = np.linspace(0.0, 200.0, 4001)
    s = _motion(t, seed=3)
    warm = FrictionWarmup.from_config({"viscous": 0.3, "coulomb": 0.2, "time_constant": 40.0}, N_J)
    tau = warm.torque(s)
    assert np.all(tau * s.qd >= 0.0)                                    # never injects energy
    early = np.abs(tau[t < 20]).max(axis=0)
    late = np.abs(tau[t > 180]).max(axis=0)
    assert np.all(late < 0.05 * early)                                  # exp(−180/40) ≈ 1 %
    # the same motion later in the session sees less friction
    later = warm.torque(MotionSignals(t + 100.0, s.q, s.qd, s.qdd))
    np.testing.assert_allclose(later, tau * np.exp(-100.0 / 40.0), atol=1e-12)


def test_twin_config_session_time_is_validated_and_logged():
    from proprio.diagrams.twin import TwinConfigError, load_twin_config
    from proprio.systems.joint_drive import JointDrive

    base = load_twin_config("iiwa14_twin")
    assert base.session_time_s == 0.0 and base.meta()["session_time_s"] == 0.0
    cfg = type(base).from_dict({**base.raw, "session_time_s": 90.0}, "t.yaml")
    assert cfg.session_time_s == 90.0 and cfg.meta()["session_time_s"] == 90.0
    for bad in (-1.0, "soon", float("nan")):
        with pytest.raises(TwinConfigError, match="session_time_s"):
            type(base).from_dict({**base.raw, "session_time_s": bad}, "t.yaml")
    with pytest.raises(TwinConfigError, match="session_time_s"):
        base.with_session_time(-5.0)
    warm = FrictionWarmup(N_J, viscous=0.2, coulomb=0.1, time_constant=30.0)
    qd = np.full((3, N_J), 0.4)
    drive = JointDrive(N_J, [warm], session_time_s=60.0)
    t = np.array([0.0, 10.0, 20.0])
    np.testing.assert_allclose(drive.link_torque(t, np.zeros_like(qd), qd), warm.friction(qd, t + 60.0))


@lru_cache(maxsize=8)
def _gap(case: BenchmarkCase) -> tuple[SimModel, GapData, GapData]:
    d = generate_case_data(case)
    model = SimModel(d.robot, tuple(EFFECTS[k](d.robot.n, **d.model_params[k]) for k in d.model_effects))
    out = []
    for recs, role in ((d.train, "training"), (d.holdout, "holdout")):
        cond = condition_all(recs, DIAGNOSIS_CONDITIONING, role)
        out.append(GapData.build(model, cond, [kept(c, 0.5) for c in cond], role,
                                 session_s=[session_time(r) for r in recs]))
    return model, out[0], out[1]


def _short(name: str) -> BenchmarkCase:
    cases = {c.name: c for c in time_varying_cases() + make_cases()}
    return replace(cases[name], duration_s=SHORT_S)


@pytest.mark.parametrize("name,kind", [("time:offset_drift@1", "offset"), ("time:friction_warmup@1", "friction"),
                                       ("time:offset_step@1", "offset step")])
def test_time_dependence_is_detected(name, kind):
    model, train, hold = _gap(_short(name))
    assert hold.session_s == [SESSION_S[2]]
    # the model and the candidates see the session clock
    assert hold.signals[0].t[0] == pytest.approx(SESSION_S[2] + hold.conditioned[0].t[0])
    tv = time_variation(model, train, hold)
    assert tv.detected and tv.joints.sum() >= 3
    assert kind in tv.kind
    assert tv.text.startswith("the gap depends on when the data were taken")
    assert np.all(tv.p_value[tv.joints] < 0.01 / N_J)


@pytest.mark.parametrize("name", ["null#0", "rigid_body@1", "load_friction@0.5"])
def test_static_gap_is_not_taken_for_a_time_dependence(name):
    # the same session clock as the time cases: a static gap must not look like a drift or a step (a Coulomb level
    # that grows with the load read as a friction change, joint 3 at p = 5e-5, before the static design held it)
    model, train, hold = _gap(replace(_short(name), session_s=SESSION_S))
    tv = time_variation(model, train, hold)
    assert not tv.detected, tv.text
    assert tv.kind == "" and tv.text.startswith("no dependence")


@pytest.mark.parametrize("name,sessions", [("open:neighbour_drag@1", ()), ("open:cross_talk@2", SESSION_S)])
def test_static_effect_the_library_lacks_is_not_taken_for_time(name, sessions):
    """An out-of-library static effect leaves, in each recording, whatever trend its recording's motion gives (drag
    from the next joint's speed: joint 3's residual trended within the recordings, p = 4e-4 < 0.01/7 with a slope per
    recording); a time dependence is one function of the session clock shared by every recording."""
    case = replace(_short(name), session_s=sessions)
    model, train, hold = _gap(case)
    tv = time_variation(model, train, hold)
    assert not tv.detected, tv.text
    # ... while the effect is there, structured and large against the background noise
    assert np.sqrt((hold.residual ** 2).mean(axis=0)).max() > 0.15


def test_nuisance_keeps_a_drift_out_of_the_rigid_body():
    model, train, hold = _gap(_short("time:offset_drift@1"))
    w = 1.0 / (train.residual ** 2).mean(axis=0)
    rigid = RigidBodyCandidate(model.robot, train)
    nuisance = TimeTrendNuisance(train)
    assert not np.any(nuisance.design(hold))                     # predicts nothing on the held-out data
    gains = []
    for cands in ([rigid], [rigid, nuisance]):
        fit = fit_candidates(cands, train, w, {})
        r = hold.residual - predict_candidates([rigid], fit, hold)
        gains.append(1.0 - float((r ** 2).sum()) / float((hold.residual ** 2).sum()))
    assert gains[1] < gains[0] - 0.05                           # the trend no longer carries over by chance


def test_session_time_errors_name_the_field():
    d = generate_case_data(replace(_short("null#0"), duration_s=4.0))
    rec = d.train[0]
    assert session_time(rec) == 0.0
    bad = replace(rec, meta={**rec.meta, "session_time_s": "late"})
    with pytest.raises(DiagnosisError, match="session_time_s"):
        session_time(bad, "training recording 0")


def test_twin_simulates_time_varying_effects_on_the_session_clock():
    from pydrake.trajectories import PiecewisePolynomial

    from proprio.diagrams.twin import load_twin_config, simulate_twin

    q_a = np.array([0.1, 0.5, -0.2, -1.2, 0.3, 0.7, 0.2])
    rng = np.random.default_rng(0)
    knots = q_a + rng.uniform(-0.25, 0.25, (4, N_J))
    knots[0] = q_a
    traj = PiecewisePolynomial.CubicShapePreserving(np.linspace(0.0, 1.0, 4), knots.T, True)
    base = load_twin_config("iiwa14_twin")
    warm = FrictionWarmup(N_J, viscous=0.3, coulomb=0.2, time_constant=40.0, smooth_velocity=0.05)
    drift = OffsetDrift(N_J, offset=0.1, drift=0.5, time_constant=60.0)
    cfg = base.with_effects([e for e in base.effects] + [warm, drift]).with_session_time(30.0)
    rec = simulate_twin(cfg, traj, progress=False)
    tr = rec.truth
    assert rec.meta["session_time_s"] == 30.0 and "friction_warmup" in rec.meta["effects"]
    # the simulated τ_J holds the warm-up friction (evaluated per step at the session time) ...
    np.testing.assert_allclose(tr["tau_J_true"], tr["tau_rbd"] + tr["tau_viscous_coulomb"]
                               + tr["tau_friction_warmup"], atol=1e-6)
    # t_true is on the logged stamps' clock, which starts at the first (jittered, ≤ 1 ms) stamp: rtol 1e-4
    s = MotionSignals(tr["t_true"] + 30.0, tr["q_true"], tr["qd"], tr["qdd"])
    np.testing.assert_allclose(tr["tau_friction_warmup"], warm.torque(s), rtol=1e-4, atol=1e-9)
    # ... and the measured τ the drifting offset, 30 s into the session
    np.testing.assert_allclose(tr["tau_offset_drift"], drift.offset_at(s.t), rtol=1e-4)
    assert tr["tau_offset_drift"][0, 0] == pytest.approx(0.1 + 0.5 * (1 - np.exp(-0.5)), abs=2e-3)


def test_candidate_set_offers_time_varying_effects_only_when_asked():
    model, train, _ = _gap(_short("time:offset_drift@1"))
    static = {c.name for c in candidate_set(model, train)}
    varying = {c.name for c in candidate_set(model, train, time_varying=True)}
    assert {"rigid_body", "payload", "sensor_offset", "sensor_gain", "signal_lag", "viscous_coulomb"} <= static
    assert varying - static == {"offset_drift", "friction_warmup"}
    assert [c.name for c in candidate_set(model, train, ["offset_drift"])] == ["offset_drift"]     # when named


def _growing(robot, seed: int, effects):
    """A recording whose motion grows with time at a steady speed (a designed experiment's growing triangles): per
    joint ``q = A(t)·sin θ(t)`` with the amplitude ramping 0.3° → 12° over :data:`SHORT_S` and ``θ̇ = v/A`` (peak
    speed ``v`` throughout, ever slower reversals); the rigid body + ``effects``, noise as the benchmark's."""
    from proprio.gap_benchmark.recordings import NOISE_STD
    from proprio.dynamics import inverse_dynamics
    from proprio.recording import Recording

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, SHORT_S, 1e-3)[:, None]
    a0, a1, v = np.radians(0.3), np.radians(12.0), rng.uniform(0.15, 0.25, N_J)
    k = (a1 - a0) / SHORT_S
    q = (a0 + k * t) * np.sin(v / k * np.log1p(k * t / a0)) + np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
    qd = np.gradient(q, 1e-3, axis=0)
    qdd = np.gradient(qd, 1e-3, axis=0)
    s = MotionSignals(t[:, 0], q, qd, qdd)
    tau = inverse_dynamics(robot, q, qd, qdd)
    for eff in effects:
        tau = tau + eff.torque(s.with_tau(tau))
    keep = slice(None, None, 5)                                          # logged at 200 Hz
    return Recording(t=t[keep, 0], q=q[keep], tau=tau[keep] + rng.normal(0.0, NOISE_STD, tau[keep].shape),
                     meta={"robot": robot.name})


def test_motion_that_grows_with_time_is_not_taken_for_a_friction_change():
    """A saturating static loop on a motion whose amplitude grows with time (the designed experiment of
    tests/test_ambiguity.py) puts a rising level into e·sign q̇; the reversal shapes of the static design take it
    (without them joint 2 read as a friction change of 0.22 N·m, p = 2e-5), while a real warm-up on the same motion
    is found."""
    from proprio.description import load_robot
    from proprio.diagnosis.selection.time_variation import REVERSAL_SCALES_DEG, reversal_shapes

    robot = load_robot("iiwa14_nominal")
    model = SimModel(robot)
    loop = EFFECTS["hysteresis"](N_J, saturation=np.full(N_J, 0.3), saturation_travel=np.full(N_J, np.radians(2.0)))

    def gap(effects):
        out = []
        for role, seeds in (("training", (1, 2)), ("holdout", (3,))):
            recs = [_growing(robot, k, effects) for k in seeds]
            cond = condition_all(recs, DIAGNOSIS_CONDITIONING, role)
            out.append(GapData.build(model, cond, [kept(c, 0.5) for c in cond], role))
        return out

    train, hold = gap([loop])
    shapes = reversal_shapes(N_J, train)
    assert shapes.shape == (sum(len(i) for i in train.fit_index), N_J, N_J * len(REVERSAL_SCALES_DEG))
    assert np.all(shapes[:, 0, len(REVERSAL_SCALES_DEG):] == 0)          # each joint's shapes on its own rows
    tv = time_variation(model, train, hold)
    assert not tv.detected, tv.text
    warm = FrictionWarmup(N_J, viscous=np.full(N_J, 0.3), coulomb=np.full(N_J, 0.3), time_constant=np.full(N_J, 5.0))
    tv = time_variation(model, *gap([loop, warm]))
    assert tv.detected and "friction" in tv.kind, tv.text
