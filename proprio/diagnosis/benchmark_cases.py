"""The withheld-effect benchmark's cases and their data (:mod:`proprio.diagnosis.benchmark` runs and scores them).

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
(:data:`TWIN_EFFECT_TYPES`) and payload; null and two-effect cases as above. Scores are computed by the same
:func:`summarise`. The measured shrinkage still counts only the sensor noise as what remains, so in twin mode it is
an upper bound: the controller's tracking and the differentiation of q leave a little more.

**Out-of-library cases** (:func:`open_world_cases`, ``open:<type>@<mag>``; in twin mode ``twin:open:...``): an
effect no library class expresses (:data:`OPEN_WORLD_TYPES`: the plugins of :mod:`proprio.effects.open_world`,
reached only through their plugin paths, as a user's own effect) at magnitudes 1 and 2 on one drawn joint, the
model without it. The right answer is "structured, outside the candidate set": no library effect named above 5 %
held-out gain, and a hint naming the case's ``expected_signal`` on that joint. 

**Time-varying cases** (:func:`time_varying_cases`): the gap depends on when the data were taken. The three
recordings are placed on the session clock at ``BenchmarkCase.session_s`` (training first, the held-out one last:
0, 25, 50 s offline; 0, 35, 70 s through the twin), written to ``Recording.meta["session_time_s"]``. Kinds
(:data:`TIME_TYPES`): ``offset_drift`` (a drifting torque-sensor offset, time constant 30–90 s), ``friction_warmup``
(cold-gearbox excess friction fading with a time constant of 20–60 s) and ``offset_step`` (the sensor offset
re-zeroed between sessions: a constant offset per recording, no library effect explains it), 2 magnitudes each.
What is scored there is whether the diagnosis says the gap depends on time (``Attribution.time_variation``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np
from scipy import signal

from proprio.description import Link, RobotDescription, load_robot
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS, resolve_effect
from proprio.effects.plugins import is_plugin_path
from proprio.payload import Payload, attach_payload
from proprio.recording import Recording
from proprio.signals import MotionSignals

__all__ = ["BenchmarkCase", "CaseData", "make_cases", "time_varying_cases", "select_cases", "generate_case_data",
           "generate_twin_case_data", "twin_case_config", "rfma_like_motion", "EFFECT_TYPES", "TWIN_EFFECT_TYPES",
           "PROCESSING_TYPES", "TIME_TYPES", "RATE_HZ", "OPEN_WORLD_TYPES", "open_world_cases", "is_open_world",
           "is_time_varying", "is_drive_case", "twin_recordings", "LINK_SENSOR_ANSWER", "DRIVE_ANSWER",
           "expected_name"]

RATE_HZ = 200.0
NOISE_STD = 0.05                 # background torque-sensor noise [N·m] (present in data AND model unless withheld)
ENCODER = {"std": np.radians(0.0005), "resolution": np.radians(0.0001)}   # background encoder noise + quantisation
#                                  [rad], the shipped twin's: every case logs measured q, never exact q, q̇, q̈; the
#                                  model states it too (a withheld encoder_noise replaces its std by a larger one)
PROCESSING_TYPES = ("signal_lag", "encoder_noise")   # data-path cases: scored against the processing section
TIME_TYPES = ("offset_drift", "friction_warmup", "offset_step")   # time-varying cases (time_varying_cases)
SESSION_S = (0.0, 25.0, 50.0)    # s, session time of the 2 training and the held-out recording (offline)
TWIN_SESSION_S = (0.0, 35.0, 70.0)   # s, the same through the twin (≈30 s recordings)
EXTRA_TYPES = ("rigid_body", "payload", "signal_lag")
STATIC_EFFECTS = tuple(k for k, cls in EFFECTS.items() if not cls.time_varying)   # time-varying: time_varying_cases
EFFECT_TYPES = STATIC_EFFECTS + EXTRA_TYPES
# twin mode: every effect of the shipped iiwa14_twin.yaml, plus the payload (TwinConfig.with_payload)
TWIN_EFFECT_TYPES = ("viscous_coulomb", "hysteresis", "lost_motion", "ripple", "sensor_offset_gain", "torque_noise",
                     "encoder_noise", "payload")
# out-of-library effects, reached only through their plugin paths: short name → (plugin path, joints (0-based) the
# effect may act on, the hint signal of joint j as a function of j: "tau_<k>", "q_<k>", "qd_<k>" with 1-based k)
_OW = "proprio.effects.open_world"
OPEN_WORLD_TYPES: dict[str, tuple[str, tuple[int, ...], Any]] = {
    "cross_talk": (f"{_OW}:TorqueCrossTalk", (0, 2), lambda j: f"tau_{j + 2}"),     # next joint gravity-loaded
    "position_friction": (f"{_OW}:PositionFriction", (0, 1, 2, 3, 4, 5, 6), lambda j: f"q_{j + 1}"),
    "cable_spring": (f"{_OW}:CableSpring", (0,), lambda j: f"q_{j + 2}"),      # joint 1: no gravity term
    "neighbour_drag": (f"{_OW}:NeighbourDrag", (0, 1, 2, 3, 4, 5), lambda j: f"qd_{j + 2}"),
}


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


# ---------------------------------------------------------------------------------------------------------------
# cases
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BenchmarkCase:
    """``withheld``: effect types present in the data and absent from the model (empty = null case);
    ``modelled``: library effects present in the data and in the model (same parameters); ``magnitude`` scales
    the withheld effects' base level; ``seed`` draws their parameters and the motion; ``twin``: the recordings
    come from the Drake twin diagram on RFMA trajectories (``duration_s`` unused) instead of the offline model;
    ``logger``: ``(field, value)`` pairs that change the twin's logger (default: 200 Hz, the shipped jitter and
    losses), e.g. ``(("rate_hz", 1000.0), ("dropout_prob", 0.02))``; ``session_s``: the session time [s] at the start
    of each of the 3 recordings (2 training, 1 held-out; empty: 0 each)."""
    name: str
    withheld: tuple[str, ...]
    magnitude: float
    seed: int
    modelled: tuple[str, ...] = ()
    duration_s: float = 20.0
    twin: bool = False
    logger: tuple[tuple[str, Any], ...] = ()
    session_s: tuple[float, ...] = ()
    open_joint: int = -1                 # out-of-library cases: the joint (0-based) the withheld plugin acts on
    expected_signal: str = ""            # ... and the signal a hint should name for it ("tau_3", "q_1", "qd_2")


def is_open_world(case: BenchmarkCase) -> bool:
    """An out-of-library case: its withheld effect is a plugin (no library candidate can express it)."""
    return any(is_plugin_path(k) for k in case.withheld)


def is_drive_case(case: BenchmarkCase) -> bool:
    """A case of the drive-torque family (:mod:`proprio.diagnosis.benchmark_drive`)."""
    return case.name.startswith("drive:")


LINK_SENSOR_ANSWER = {"presliding": "hysteresis"}
"""The name the diagnosis should give a withheld effect of a link-side torque sensor's arm when it is not the
effect's own: the drive's pre-sliding friction is, in τ_J, the Dahl law the diagnosis offers as the gauge's
``hysteresis`` (:data:`proprio.diagnosis.drive_candidates.DRIVE_ONLY`; ``proprio/effects/dahl.py``)."""

DRIVE_ANSWER = {"coupled_motor_friction": "motor_friction"}
"""The same for the drive family: a shared motor's friction is the ``motor_friction`` candidate on the description's
coupling (:class:`proprio.diagnosis.drive_candidates.DriveCandidate`)."""


def expected_name(case: BenchmarkCase) -> str:
    """The top-1 name a single-effect case is right with: its withheld effect, under :data:`LINK_SENSOR_ANSWER`
    (:data:`DRIVE_ANSWER` when the arm's τ is the drive torque: the drive family)."""
    kind = case.withheld[0]
    return (DRIVE_ANSWER if is_drive_case(case) else LINK_SENSOR_ANSWER).get(kind, kind)


def is_time_varying(case: BenchmarkCase) -> bool:
    """A case whose withheld effect varies with time (:data:`TIME_TYPES`)."""
    return bool(set(case.withheld) & set(TIME_TYPES))


def _draw_open(kind: str, n: int, mag: float, joint: int, rng: np.random.Generator) -> dict[str, Any]:
    """Parameters of an out-of-library plugin at magnitude ``mag``, acting on ``joint`` only (zero elsewhere)."""
    one = lambda x: np.where(np.arange(n) == joint, x, 0.0)  # noqa: E731
    sign = float(rng.choice([-1.0, 1.0]))
    name = kind.rpartition(":")[2]
    if name == "TorqueCrossTalk":                   # 2–4 % of the neighbour's torque (tens of N·m on joints 2–4)
        return {"coupling": one(sign * mag * rng.uniform(0.02, 0.04))}
    if name == "PositionFriction":                  # 0.3–0.6 N·m, a pattern of 4–6 rad⁻¹ along the stroke
        amp, ph = mag * rng.uniform(0.3, 0.6), rng.uniform(0, 2 * np.pi)
        return {"cos_amplitude": one(amp * np.cos(ph)), "sin_amplitude": one(amp * np.sin(ph)),
                "order": rng.uniform(4.0, 6.0, n)}
    if name == "CableSpring":                       # 0.5–1 N·m/rad: ≈1 N·m over a reach of a radian of joint j+1
        return {"stiffness": one(mag * rng.uniform(0.5, 1.0)), "reference": rng.uniform(-0.3, 0.3, n)}
    if name == "NeighbourDrag":                     # 0.3–0.6 N·m when the next joint turns
        return {"drag": one(sign * mag * rng.uniform(0.3, 0.6))}
    raise ValueError(f"unknown out-of-library benchmark effect {kind!r}")


def _draw(kind: str, n: int, mag: float, rng: np.random.Generator, joint: int = -1) -> dict[str, Any]:
    """Parameters of one effect at magnitude ``mag`` (base levels from DESIGN.md's calibration ranges; a plugin
    of :data:`OPEN_WORLD_TYPES` acts on ``joint`` only)."""
    if is_plugin_path(kind):
        return _draw_open(kind, n, mag, joint, rng)
    u = lambda a, b: rng.uniform(a, b, n)  # noqa: E731
    if kind == "viscous_coulomb":
        return {"viscous": mag * u(0.10, 0.37), "coulomb": mag * u(0.03, 0.32)}
    if kind == "stribeck":
        return {"static": mag * u(0.15, 0.45), "stribeck_velocity": u(0.02, 0.08)}
    if kind == "hysteresis":
        return {"saturation": mag * u(0.1, 0.5), "saturation_travel": np.radians(u(4.0, 8.0))}
    if kind == "lost_motion":
        return {"amplitude": mag * u(0.15, 0.45), "window": np.radians(u(0.7, 1.5))}
    if kind == "ripple":
        amp, ph = mag * u(0.05, 0.2), u(0, 2 * np.pi)
        return {"sin_amplitude": amp * np.cos(ph), "cos_amplitude": amp * np.sin(ph), "gear_ratio": u(100, 160),
                "harmonic": 2.0}
    if kind == "sensor_offset_gain":
        return {"offset": mag * u(0.1, 0.9) * rng.choice([-1, 1], n), "gain": mag * u(-0.02, 0.02)}
    if kind == "torque_noise":
        return {"std": mag * u(0.05, 0.15)}
    if kind == "encoder_noise":
        return {"std": mag * u(2e-5, 8e-5)}
    if kind == "elasticity":
        return {"stiffness": u(4000.0, 15000.0) / mag}
    if kind == "presliding":                     # 0.3–0.8 N·m, turning over within 0.2–1° of travel
        return {"level": mag * u(0.3, 0.8), "presliding_travel": np.radians(u(0.2, 1.0))}
    if kind == "rigid_body":
        return {"mass_scale": 1 + mag * u(-0.15, 0.15), "com_shift": mag * rng.uniform(-0.02, 0.02, (n, 3))}
    if kind == "payload":
        return {"mass": float(mag * rng.uniform(0.5, 2.0)), "com": rng.uniform(-0.03, 0.03, 3) + [0, 0, 0.05]}
    if kind == "signal_lag":
        return {"time_constant": float(mag * rng.uniform(0.004, 0.012))}
    if kind == "offset_drift":
        return {"drift": mag * u(0.3, 0.9) * rng.choice([-1, 1], n), "time_constant": u(30.0, 90.0)}
    if kind == "friction_warmup":
        return {"viscous": mag * u(0.1, 0.37), "coulomb": mag * u(0.1, 0.32), "time_constant": u(20.0, 60.0)}
    if kind == "offset_step":                    # one offset per recording (re-zeroed between sessions)
        return {"offsets": mag * rng.uniform(0.2, 0.6, (3, n)) * rng.choice([-1, 1], (3, n))}
    raise ValueError(f"unknown benchmark effect {kind!r}")


def make_cases(quick: bool = False, seed: int = 0, twin: bool = False) -> list[BenchmarkCase]:
    """The case list: every effect type × magnitudes (0.5, 1, 2; quick: 1) + null cases + two-effect cases.

    ``twin``: the twin-diagram cases instead (:data:`TWIN_EFFECT_TYPES`; quick: 4 single, 1 null, 1 pair). Both
    lists end with the out-of-library cases (:func:`open_world_cases`; quick: 1) and the time-varying ones
    (:func:`time_varying_cases`; quick: 1)."""
    extra = open_world_cases(quick, seed, twin) + time_varying_cases(quick, seed, twin)
    if twin:
        return _twin_cases(quick, seed) + extra
    rng = np.random.default_rng(seed)
    mags = (1.0,) if quick else (0.5, 1.0, 2.0)
    cases = []
    for kind in EFFECT_TYPES:
        for m in mags:
            s = int(rng.integers(1 << 30))
            cases.append(BenchmarkCase(f"{kind}@{m:g}", (kind,), m, s))
    library = [k for k in STATIC_EFFECTS if k not in ("torque_noise", "encoder_noise", "elasticity")]
    for k in range(2 if quick else 6):
        present = tuple(sorted(rng.choice(library, size=k % 3, replace=False))) if k else ()
        cases.append(BenchmarkCase(f"null#{k}" + (f"({'+'.join(present)})" if present else ""), (), 1.0,
                                   int(rng.integers(1 << 30)), modelled=present))
    pairs = [("viscous_coulomb", "sensor_offset_gain"), ("hysteresis", "ripple"), ("payload", "stribeck"),
             ("rigid_body", "viscous_coulomb"), ("lost_motion", "sensor_offset_gain"), ("elasticity", "ripple")]
    for a, b in pairs[:1 if quick else len(pairs)]:
        cases.append(BenchmarkCase(f"{a}+{b}", (a, b), 1.0, int(rng.integers(1 << 30))))
    return cases + extra


def open_world_cases(quick: bool = False, seed: int = 0, twin: bool = False) -> list[BenchmarkCase]:
    """Out-of-library cases: every :data:`OPEN_WORLD_TYPES` plugin at magnitudes 1 and 2 on a drawn joint (quick:
    the first type at magnitude 1), the model without it; named ``open:<type>@<mag>`` (``twin:open:...`` in twin
    mode). The diagnosis should flag the residual as structured and unexplained, name no library effect, and its
    hints should name the case's ``expected_signal``."""
    rng = np.random.default_rng([seed, 13])
    prefix = "twin:" if twin else ""
    cases = []
    for short, (path, joints, signal_of) in list(OPEN_WORLD_TYPES.items())[:1 if quick else None]:
        for m in (1.0,) if quick else (1.0, 2.0):
            j = int(rng.choice(joints))
            cases.append(BenchmarkCase(f"{prefix}open:{short}@{m:g}", (path,), m, int(rng.integers(1 << 30)),
                                       twin=twin, open_joint=j, expected_signal=signal_of(j)))
    return cases


def time_varying_cases(quick: bool = False, seed: int = 0, twin: bool = False) -> list[BenchmarkCase]:
    """The time-varying cases (module docstring): every kind of :data:`TIME_TYPES` at magnitudes 0.5 and 1 (quick:
    ``offset_drift`` at 1), recordings at :data:`SESSION_S` (``twin``: through the Drake twin at
    :data:`TWIN_SESSION_S`). Names ``time:<kind>@<magnitude>`` (``twin:time:...`` through the twin)."""
    rng = np.random.default_rng(seed + 13)
    kinds = ("offset_drift",) if quick else TIME_TYPES
    prefix = "twin:time:" if twin else "time:"
    cases = []
    for kind in kinds:
        for m in (1.0,) if quick else (0.5, 1.0):
            cases.append(BenchmarkCase(f"{prefix}{kind}@{m:g}", (kind,), m, int(rng.integers(1 << 30)), twin=twin,
                                       session_s=TWIN_SESSION_S if twin else SESSION_S))
    return cases


def _session(case: BenchmarkCase, k: int) -> float:
    """Session time [s] at the start of the case's recording ``k``."""
    return float(case.session_s[k]) if case.session_s else 0.0


def _twin_cases(quick: bool, seed: int) -> list[BenchmarkCase]:
    """The library's twin cases (:func:`make_cases` adds the out-of-library and time-varying ones)."""
    rng = np.random.default_rng(seed)
    mags = (0.5, 1.0, 2.0)
    kinds = ("viscous_coulomb", "hysteresis", "sensor_offset_gain", "payload") if quick else TWIN_EFFECT_TYPES
    cases = []
    for kind in kinds:
        for m in (1.0,) if quick else mags:
            cases.append(BenchmarkCase(f"twin:{kind}@{m:g}", (kind,), m, int(rng.integers(1 << 30)), twin=True))
    library = [k for k in TWIN_EFFECT_TYPES if k not in ("payload", "torque_noise", "encoder_noise")]
    for k in range(1 if quick else 4):
        present = tuple(sorted(rng.choice(library, size=k % 3, replace=False))) if k else ()
        cases.append(BenchmarkCase(f"twin:null#{k}" + (f"({'+'.join(present)})" if present else ""), (), 1.0,
                                   int(rng.integers(1 << 30)), modelled=present, twin=True))
    pairs = [("viscous_coulomb", "sensor_offset_gain"), ("hysteresis", "ripple"), ("payload", "viscous_coulomb"),
             ("lost_motion", "sensor_offset_gain")]
    for a, b in pairs[:1 if quick else len(pairs)]:
        cases.append(BenchmarkCase(f"twin:{a}+{b}", (a, b), 1.0, int(rng.integers(1 << 30)), twin=True))
    return cases


@dataclass
class CaseData:
    robot: RobotDescription
    model_effects: tuple[str, ...]
    model_params: dict[str, dict[str, Any]]
    train: list[Recording]
    holdout: list[Recording]


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
        from proprio.diagnosis.benchmark_drive import generate_drive_case_data
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
        s = MotionSignals(t + _session(case, k), q, qd, qdd)          # effects see the session clock
        tau = inverse_dynamics(data_robot, q, qd, qdd)
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


def twin_recordings(case: BenchmarkCase, configs: list[Any], meta: dict[str, Any] | None = None) -> list[Recording]:
    """The case's 3 recordings through the twin (``configs``: one ``TwinConfig`` per recording): short RFMA
    trajectories (2 scaffolds, 600–800 waypoints per exploration, own seed per recording; a seed for which RFMA finds
    no collision-free reach is replaced by a derived one), logged by each config's logger (q, τ; f_ext dropped);
    ``meta`` is added to each Recording's."""
    from proprio.diagrams.twin import simulate_twin
    from proprio.systems.rfma import RfmaError, generate_rfma, load_rfma_config

    recs = []
    for k in range(3):
        seed = (case.seed + 7919 * k) % (1 << 31)
        for attempt in range(5):                # RFMA may find no collision-free reach: next seed
            try:
                _, timed = generate_rfma(load_rfma_config(scaffolds=2, seed=seed, waypoints=(600, 800)),
                                         configs[k].robot)
                break
            except RfmaError:
                if attempt == 4:
                    raise
                seed = (seed + 104729) % (1 << 31)
        rec = simulate_twin(replace(configs[k], seed=seed), timed.trajectory, progress=False)
        meta_k = {**rec.meta, "source": "gap-benchmark (twin)", **(meta or {})}
        recs.append(Recording(t=rec.t, q=rec.q, tau=rec.tau, truth=rec.truth, meta=meta_k))
    return recs


def select_cases(cases: list[BenchmarkCase], names: list[str] | None) -> list[BenchmarkCase]:
    """The cases named in ``names`` (all when ``None``), in the list's order; an unknown name is an error."""
    if names is None:
        return cases
    known = {c.name for c in cases}
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"unknown benchmark case(s) {bad}; this case list has: {', '.join(c.name for c in cases)}")
    return [c for c in cases if c.name in set(names)]
