"""The withheld-effect benchmark's data: what each case of :mod:`proprio.gap_benchmark.cases` records and the
model it is diagnosed with (:mod:`proprio.gap_benchmark.run` runs and scores them).

**How the data are made (stated, as the benchmark is offline):** motion is an RFMA-like sequence generated here in
closed form (min-jerk *reach* segments between random configurations at up to ≈70 % of the speed limits, then
*exploration* segments: a smoothly windowed 3-term sinusoid of 0.5–3° per joint, §4.3), sampled at 200 Hz; the
measured torque is ``τ_J = τ_rbd(q, q̇, q̈) + Σ effect.torque(...)`` with the library's own effect classes (link-side
friction first, then sensor effects on the resulting τ_J) plus white sensor noise; encoder noise and elasticity act
on the *recorded* q (encoder noise + quantisation; a motor-side position sensor that sees the spring deflection
τ_J/K), which is how they reach a torque residual. Recordings store q only (q̇, q̈ are differentiated by the
diagnosis, as from a real recorder). The model carries the background noise the data were made with: torque noise
(unless withheld) and the encoder's stated noise and quantisation, against which the diagnosis compares the data's
position-noise floor (:mod:`proprio.diagnosis.encoder_floor`). This applies the twin's effect library offline to
twin-like motion; it does not run the Drake twin diagram (``diagrams/twin.py``).

**Twin mode** (``make_cases(twin=True)``, ``proprio gap-benchmark --twin``): the recordings come from the Drake
twin diagram instead, i.e. twin data with the effect present and a sim model without it. Each case's twin is the
shipped ``iiwa14_twin`` (real robot ``iiwa14_identified``, inverse-dynamics controller, hidden motor-side drive)
with its joint effects replaced by the case's withheld + modelled effects (parameters drawn as above, at the case's
magnitude) and the background noise; a withheld payload is attached with ``TwinConfig.with_payload``. It runs
:func:`proprio.diagrams.twin.simulate_twin` along short RFMA trajectories (``proprio.systems.rfma``: 2 scaffolds,
600–800 waypoints per exploration, ≈30 s each; separate seeds for the 2 training and the held-out recording), with
the shipped twin's logger at 200 Hz: encoder q and τ only, jittered stamps and lost samples, as a real robot logs
(q̇, q̈ come from the diagnosis' conditioning). The model
is ``iiwa14_identified`` without friction + the modelled effects. Effect types: those of ``iiwa14_twin.yaml``
(:data:`proprio.gap_benchmark.cases.TWIN_EFFECT_TYPES`) and payload; null and two-effect cases as above.
Scores are computed by the same :func:`proprio.gap_benchmark.run.summarise`. The measured shrinkage still counts
only the sensor noise as what remains, so in twin mode it is an upper bound: the controller's tracking and the
differentiation of q leave a little more.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from scipy import signal

from proprio.description import Link, RobotDescription, load_robot
from proprio.gap_benchmark.cases import TIME_TYPES, TWIN_EFFECT_TYPES, BenchmarkCase, _draw, is_drive_case
from proprio.gap_benchmark.drive import generate_drive_case_data
from proprio.gap_benchmark.recordings import ENCODER, NOISE_STD, CaseData, twin_recordings
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS, resolve_effect
from proprio.effects.plugins import is_plugin_path
from proprio.payload import Payload, attach_payload
from proprio.recording import Recording
from proprio.signals import MotionSignals

__all__ = ["generate_case_data", "generate_twin_case_data", "twin_case_config", "rfma_like_motion", "RATE_HZ"]

RATE_HZ = 200.0


# ---------------------------------------------------------------------------------------------------------------
# motion
# ---------------------------------------------------------------------------------------------------------------
def _minjerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = 10 * tau ** 3 - 15 * tau ** 4 + 6 * tau ** 5
    ds = 30 * tau ** 2 - 60 * tau ** 3 + 30 * tau ** 4
    dds = 60 * tau - 180 * tau ** 2 + 120 * tau ** 3
    return s, ds, dds


def rfma_like_motion(robot: RobotDescription, seed: int, duration: float, rate_hz: float = RATE_HZ
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``t, q, q̇, q̈, segment`` (1 = reach, 0 = exploration) of alternating reach/explore segments (module doc)."""
    rng = np.random.default_rng(seed)
    n = robot.n
    lo, hi = robot.lower, robot.upper
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    vlim = robot.velocity_limits
    t = np.arange(0.0, duration, 1.0 / rate_hz)
    q = np.empty((len(t), n))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    seg = np.zeros(len(t))
    q_now = mid + rng.uniform(-0.4, 0.4, n) * half
    t0 = 0.0
    reach = True
    while t0 < duration:
        if reach:
            q_next = mid + rng.uniform(-0.55, 0.55, n) * half
            dist = np.abs(q_next - q_now)
            frac = rng.uniform(0.3, 0.7)
            T = max(1.0, float(np.max(1.875 * dist / (frac * vlim))))
            m = (t >= t0) & (t < t0 + T)
            tau = (t[m] - t0) / T
            s, ds, dds = _minjerk(tau)
            q[m] = q_now + s[:, None] * (q_next - q_now)
            qd[m] = ds[:, None] * (q_next - q_now) / T
            qdd[m] = dds[:, None] * (q_next - q_now) / T ** 2
            seg[m] = 1
            q_now = q_next
        else:
            T = rng.uniform(3.0, 5.0)
            m = (t >= t0) & (t < t0 + T)
            tt = t[m] - t0
            amp = np.radians(rng.uniform(0.5, 3.0, (3, n)))
            f = rng.uniform(0.3, 1.2, (3, n))
            ph = rng.uniform(0, 2 * np.pi, (3, n))
            w = 2 * np.pi * f
            arg = w[None] * tt[:, None, None] + ph[None]
            x = (amp * np.sin(arg)).sum(axis=1)
            xd = (amp * w * np.cos(arg)).sum(axis=1)
            xdd = (-amp * w ** 2 * np.sin(arg)).sum(axis=1)
            ramp = np.minimum(np.minimum(tt, T - tt) / 0.4, 1.0)
            s, ds, dds = _minjerk(ramp)
            sgn = np.where(tt < T / 2, 1.0, -1.0) / 0.4
            ds, dds = ds * sgn * (ramp < 1), dds / 0.16 * (ramp < 1)
            q[m] = q_now + s[:, None] * x
            qd[m] = ds[:, None] * x + s[:, None] * xd
            qdd[m] = dds[:, None] * x + 2 * ds[:, None] * xd + s[:, None] * xdd
        t0 += T
        reach = not reach
    return t, q, qd, qdd, seg


def _session(case: BenchmarkCase, k: int) -> float:
    """Session time [s] at the start of the case's recording ``k``."""
    return float(case.session_s[k]) if case.session_s else 0.0


def _perturbed(robot: RobotDescription, p: dict[str, Any]) -> RobotDescription:
    links = []
    for j, lk in enumerate(robot.links):
        links.append(Link(lk.name, lk.mass * float(p["mass_scale"][j]),
                          tuple(np.asarray(lk.com_xyz) + p["com_shift"][j]), lk.inertia_com, lk.com_rpy,
                          lk.collision))
    return robot.with_inertials(links)


def _model(modelled: dict[str, dict[str, Any]], torque_noise_withheld: bool, n: int
           ) -> tuple[tuple[str, ...], dict[str, dict[str, Any]]]:
    """The model's effect list and parameters: the modelled effects, the background torque noise (``NOISE_STD``)
    unless torque noise is what is withheld, and always the background encoder noise (``ENCODER``: the encoder's
    stated spec; a withheld ``encoder_noise`` is extra noise in the data beyond it)."""
    effects = tuple(modelled) + (() if torque_noise_withheld else ("torque_noise",)) + ("encoder_noise",)
    params = {**modelled, "torque_noise": {"std": np.full(n, NOISE_STD)},
              "encoder_noise": {k: np.full(n, v) for k, v in ENCODER.items()}}
    return effects, params


def generate_case_data(case: BenchmarkCase, robot: RobotDescription | None = None,
                       omit_withheld: bool = False, motions: Sequence[tuple] = (),
                       overrides: dict[str, dict[str, Any]] | None = None) -> CaseData:
    """Training (2 recordings) and held-out (1) data of a case, and the model's effect list (module docstring).
    Twin cases (``case.twin``) go through :func:`generate_twin_case_data` (``robot`` is then ignored).
    ``omit_withheld``: the same data (motion, noise, modelled effects, seeds) without the withheld effects — what a
    model that had them would leave (the measured floor of the shrinkage). ``motions``: ``(t, q, q̇, q̈, segment)``
    of further recordings of the same robot (a designed experiment, offline only), made instead (recordings 3, 4,
    …: own noise seeds), all returned as training recordings. ``overrides``: ``{effect: {parameter: value}}`` set
    over the drawn parameters of a withheld effect (offline only; e.g. a hysteresis that saturates within 0.5°)."""
    if is_drive_case(case):
        return generate_drive_case_data(case, omit_withheld)
    if case.twin:
        return generate_twin_case_data(case, omit_withheld)
    robot = robot or load_robot("iiwa14_nominal")
    n = robot.n
    rng = np.random.default_rng(case.seed)
    params = {k: _draw(k, n, case.magnitude, rng, case.open_joint) for k in case.withheld}
    for k, v in (overrides or {}).items():
        params[k] = {**params[k], **v}
    modelled = {k: _draw(k, n, 1.0, rng) for k in case.modelled}
    if omit_withheld:
        params = {k: v for k, v in params.items() if k == "torque_noise"}
    data_robot = robot
    if "rigid_body" in params:
        data_robot = _perturbed(data_robot, params["rigid_body"])
    if "payload" in params:
        data_robot = attach_payload(data_robot, Payload(params["payload"]["mass"], tuple(params["payload"]["com"])))
    present = {**modelled, **{k: v for k, v in params.items() if k in EFFECTS or is_plugin_path(k)}}
    steps = params.get("offset_step", {}).get("offsets")
    noise = dict(params.get("torque_noise", {"std": np.full(n, NOISE_STD)}))
    present["torque_noise"] = noise
    effects = {k: resolve_effect(k)(n, **v) for k, v in present.items()}
    model_effects, model_params = _model(modelled, "torque_noise" in params, n)
    recs = []
    for k in range(3, 3 + len(motions)) if motions else range(3):
        t, q, qd, qdd, seg = motions[k - 3] if motions else rfma_like_motion(robot, case.seed + 7919 * k,
                                                                              case.duration_s)
        tau = inverse_dynamics(data_robot, q, qd, qdd)
        # effects see the session clock; a load-dependent friction the rigid-body torque as its load
        s = MotionSignals(t + _session(case, k), q, qd, qdd, tau)
        for name, eff in effects.items():          # link-side effects and plugins (q, q̇ only, as in the twin's drive)
            if eff.place == "link":
                tau = tau + eff.torque(s)
        s = s.with_tau(tau)
        sensor = np.zeros_like(tau)
        for name, eff in effects.items():
            if eff.place == "sensor" and name not in ("torque_noise", "encoder_noise"):
                sensor += eff.torque(s)
        tau_meas = tau + sensor + (steps[k] if steps is not None else 0.0)
        if "signal_lag" in params:
            a = np.exp(-1.0 / (RATE_HZ * params["signal_lag"]["time_constant"]))
            tau_meas = signal.lfilter([1 - a], [1, -a], tau_meas - tau_meas[0], axis=0) + tau_meas[0]
        nz = effects["torque_noise"].torque(s, rng=np.random.default_rng(case.seed + k))
        tau_meas = tau_meas + nz
        q_rec = q
        if "elasticity" in params:
            q_rec = q_rec + tau / np.asarray(params["elasticity"]["stiffness"])
        enc = {**{k: np.full(n, v) for k, v in ENCODER.items()}, **params.get("encoder_noise", {})}
        q_rec = EFFECTS["encoder_noise"](n, **enc).measure(q_rec, np.random.default_rng(case.seed + 100 + k))
        recs.append(Recording(t=t, q=q_rec, tau=tau_meas, truth={"segment": seg},
                              meta={"robot": robot.name, "rate_hz": RATE_HZ, "source": "gap-benchmark (offline)",
                                    "session_time_s": _session(case, k)}))
    return CaseData(robot, model_effects, model_params, recs if motions else recs[:2], [] if motions else recs[2:])


def twin_case_config(case: BenchmarkCase, omit_withheld: bool = False, recording: int = 0
                     ) -> tuple[Any, dict[str, dict[str, Any]]]:
    """The twin of a case: the shipped ``iiwa14_twin`` (robot ``iiwa14_identified``, its controller and its hidden
    motor-side drive, whose reflected rotor inertia keeps the explicit friction stable at 1 ms) with its joint
    effects replaced by the case's withheld and modelled ones (parameters drawn as in the offline mode, ``_draw``),
    the payload via ``TwinConfig.with_payload``, and the background torque noise (``NOISE_STD``) unless that is
    what is withheld. ``recording``: which of the case's recordings (0, 1: training, 2: held-out) the twin is for —
    its session clock starts at ``case.session_s[recording]``, and an ``offset_step`` case's sensor carries that
    recording's offset. Returns ``(TwinConfig, modelled parameters)``."""
    from proprio.diagrams.twin import load_twin_config

    bad = sorted(k for k in set(case.withheld + case.modelled) - set(TWIN_EFFECT_TYPES + TIME_TYPES)
                 if not is_plugin_path(k))
    if bad:
        raise ValueError(f"twin case {case.name!r}: effect(s) {bad} cannot act in the twin; "
                         f"valid: {list(TWIN_EFFECT_TYPES + TIME_TYPES)} or a plugin 'package.module:Class'")
    config = load_twin_config("iiwa14_twin").with_payload(None).with_logger(**{"rate_hz": RATE_HZ,
                                                                              **dict(case.logger)})
    n = config.robot.n
    rng = np.random.default_rng(case.seed)
    params = {k: _draw(k, n, case.magnitude, rng, case.open_joint) for k in case.withheld}
    modelled = {k: _draw(k, n, 1.0, rng) for k in case.modelled}
    if omit_withheld:
        params = {k: v for k, v in params.items() if k == "torque_noise"}
    present = {**modelled, **{k: v for k, v in params.items() if k in EFFECTS or is_plugin_path(k)}}
    present.setdefault("torque_noise", {"std": np.full(n, NOISE_STD)})
    present["encoder_noise"] = {**{k: np.full(n, v) for k, v in ENCODER.items()}, **present.get("encoder_noise", {})}
    if "offset_step" in params:                # the sensor re-zeroed: a constant offset per session
        present["offset_drift"] = {"offset": params["offset_step"]["offsets"][recording]}
    config = config.with_effects([EFFECTS[k](n, **present[k]) for k in EFFECTS if k in present]
                                 + [resolve_effect(k)(n, **v) for k, v in present.items() if is_plugin_path(k)])
    config = config.with_session_time(_session(case, recording))
    if "payload" in params:
        config = config.with_payload(Payload(params["payload"]["mass"], tuple(params["payload"]["com"])))
    return config, modelled


def generate_twin_case_data(case: BenchmarkCase, omit_withheld: bool = False) -> CaseData:
    """Twin-mode data of a case (module docstring): 2 training + 1 held-out recordings of
    :func:`proprio.diagrams.twin.simulate_twin` (the :func:`twin_case_config` twin) along short RFMA trajectories
    (2 scaffolds, 600–800 waypoints per exploration, own seed per recording; a seed for which RFMA finds no
    collision-free reach is replaced by a derived one), logged at 200 Hz like a robot (q, τ; f_ext is dropped). Model:
    ``iiwa14_identified`` without
    friction + the modelled effects + the background torque and encoder noise (``_model``)."""
    configs = [twin_case_config(case, omit_withheld, k)[0] for k in range(3)]    # one per session (recording)
    config, modelled = twin_case_config(case, omit_withheld)
    robot = config.robot.without_friction()
    model_effects, model_params = _model(modelled, "torque_noise" in case.withheld, robot.n)
    recs = twin_recordings(case, configs)
    return CaseData(robot, model_effects, model_params, recs[:2], recs[2:])
