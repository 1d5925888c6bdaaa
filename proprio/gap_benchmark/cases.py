"""The withheld-effect benchmark's cases (:mod:`proprio.gap_benchmark.case_data` makes their data, offline or
through the Drake twin; :mod:`proprio.gap_benchmark.run` runs and scores them).

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

from dataclasses import dataclass
from typing import Any

import numpy as np

from proprio.effects import EFFECTS
from proprio.effects.plugins import is_plugin_path

__all__ = ["BenchmarkCase", "make_cases", "time_varying_cases", "select_cases", "EFFECT_TYPES", "TWIN_EFFECT_TYPES",
           "PROCESSING_TYPES", "TIME_TYPES", "OPEN_WORLD_TYPES", "open_world_cases", "is_open_world",
           "is_time_varying", "is_drive_case", "LINK_SENSOR_ANSWER", "DRIVE_ANSWER", "expected_name"]

PROCESSING_TYPES = ("signal_lag", "encoder_noise")   # data-path cases: scored against the processing section
TIME_TYPES = ("offset_drift", "friction_warmup", "offset_step")   # time-varying cases (time_varying_cases)
SESSION_S = (0.0, 25.0, 50.0)    # s, session time of the 2 training and the held-out recording (offline)
TWIN_SESSION_S = (0.0, 35.0, 70.0)   # s, the same through the twin (≈30 s recordings)
EXTRA_TYPES = ("rigid_body", "payload", "signal_lag")
LATER_TYPES = ("load_friction",)
"""Kinds added after the case lists were fixed: their cases draw their seeds from their own stream
(:func:`_later_cases`), so adding them moves no other case, and they are never drawn as a null case's modelled
effect."""
STATIC_EFFECTS = tuple(k for k, cls in EFFECTS.items() if not cls.time_varying)   # time-varying: time_varying_cases
EFFECT_TYPES = tuple(k for k in STATIC_EFFECTS if k not in LATER_TYPES) + EXTRA_TYPES + LATER_TYPES
# twin mode: every effect of the shipped iiwa14_twin.yaml, plus the payload (TwinConfig.with_payload) and the
# load-dependent friction (off in the shipped twin)
TWIN_EFFECT_TYPES = ("viscous_coulomb", "hysteresis", "lost_motion", "ripple", "sensor_offset_gain", "torque_noise",
                     "encoder_noise", "payload", "load_friction")
# out-of-library effects, reached only through their plugin paths: short name → (plugin path, joints (0-based) the
# effect may act on, the hint signal of joint j as a function of j: "tau_<k>", "q_<k>", "qd_<k>" with 1-based k)
_OW = "proprio.effects.open_world"
OPEN_WORLD_TYPES: dict[str, tuple[str, tuple[int, ...], Any]] = {
    "cross_talk": (f"{_OW}:TorqueCrossTalk", (0, 2), lambda j: f"tau_{j + 2}"),     # next joint gravity-loaded
    "position_friction": (f"{_OW}:PositionFriction", (0, 1, 2, 3, 4, 5, 6), lambda j: f"q_{j + 1}"),
    "cable_spring": (f"{_OW}:CableSpring", (0,), lambda j: f"q_{j + 2}"),      # joint 1: no gravity term
    "neighbour_drag": (f"{_OW}:NeighbourDrag", (0, 1, 2, 3, 4, 5), lambda j: f"qd_{j + 2}"),
    # a spring on joint j and a cable's sin q on joint j + 2 (two joints; last: no other case moves)
    "spring_cable": (f"{_OW}:ConfigurationTorque", (0, 2, 4), lambda j: f"q_{j + 1}"),
}


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
    """A case of the drive-torque family (:mod:`proprio.gap_benchmark.drive`)."""
    return case.name.startswith("drive:")


LINK_SENSOR_ANSWER = {"presliding": "hysteresis"}
"""The name the diagnosis should give a withheld effect of a link-side torque sensor's arm when it is not the
effect's own: the drive's pre-sliding friction is, in τ_J, the Dahl law the diagnosis offers as the gauge's
``hysteresis`` (:data:`proprio.diagnosis.candidates.drive.DRIVE_ONLY`; ``proprio/effects/dahl.py``)."""

DRIVE_ANSWER = {"coupled_motor_friction": "motor_friction"}
"""The same for the drive family: a shared motor's friction is the ``motor_friction`` candidate on the description's
coupling (:class:`proprio.diagnosis.candidates.drive.DriveCandidate`)."""


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
    if name == "ConfigurationTorque":               # 1–2 N·m/rad spring on joint j, 0.5–1 N·m sin q on joint j+2
        two = np.arange(n) == joint + 2
        return {"spring": one(mag * rng.uniform(1.0, 2.0)), "reference": rng.uniform(-0.3, 0.3, n),
                "cable": np.where(two, sign * mag * rng.uniform(0.5, 1.0), 0.0)}
    raise ValueError(f"unknown out-of-library benchmark effect {kind!r}")


def _draw(kind: str, n: int, mag: float, rng: np.random.Generator, joint: int = -1) -> dict[str, Any]:
    """Parameters of one effect at magnitude ``mag`` (base levels from DESIGN.md's calibration ranges; a plugin
    of :data:`OPEN_WORLD_TYPES` acts on ``joint`` only)."""
    if is_plugin_path(kind):
        return _draw_open(kind, n, mag, joint, rng)
    u = lambda a, b: rng.uniform(a, b, n)  # noqa: E731
    if kind == "viscous_coulomb":
        return {"viscous": mag * u(0.10, 0.37), "coulomb": mag * u(0.03, 0.32)}
    if kind == "load_friction":                  # F_c0 0.03–0.15 N·m + 1–3 % of |τ_J| (Wolf & Iskandar: a few %)
        return {"coulomb": mag * u(0.03, 0.15), "load_gain": np.minimum(mag * u(0.01, 0.03), 0.2)}
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
        if kind in LATER_TYPES:
            continue
        for m in mags:
            s = int(rng.integers(1 << 30))
            cases.append(BenchmarkCase(f"{kind}@{m:g}", (kind,), m, s))
    cases += _later_cases(seed, "", (0.5, 1.0) if quick else mags, False)
    library = [k for k in STATIC_EFFECTS if k not in ("torque_noise", "encoder_noise", "elasticity") + LATER_TYPES]
    for k in range(2 if quick else 6):
        present = tuple(sorted(rng.choice(library, size=k % 3, replace=False))) if k else ()
        cases.append(BenchmarkCase(f"null#{k}" + (f"({'+'.join(present)})" if present else ""), (), 1.0,
                                   int(rng.integers(1 << 30)), modelled=present))
    pairs = [("viscous_coulomb", "sensor_offset_gain"), ("hysteresis", "ripple"), ("payload", "stribeck"),
             ("rigid_body", "viscous_coulomb"), ("lost_motion", "sensor_offset_gain"), ("elasticity", "ripple")]
    for a, b in pairs[:1 if quick else len(pairs)]:
        cases.append(BenchmarkCase(f"{a}+{b}", (a, b), 1.0, int(rng.integers(1 << 30))))
    return cases + extra


def _later_cases(seed: int, prefix: str, mags: tuple[float, ...], twin: bool) -> list[BenchmarkCase]:
    """The cases of :data:`LATER_TYPES` at magnitudes ``mags`` (at least two: a kind is withheld at two magnitudes
    even in the quick lists), seeds from their own stream."""
    rng = np.random.default_rng([seed, 39])
    return [BenchmarkCase(f"{prefix}{kind}@{m:g}", (kind,), m, int(rng.integers(1 << 30)), twin=twin)
            for kind in LATER_TYPES for m in mags]


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


def _twin_cases(quick: bool, seed: int) -> list[BenchmarkCase]:
    """The library's twin cases (:func:`make_cases` adds the out-of-library and time-varying ones)."""
    rng = np.random.default_rng(seed)
    mags = (0.5, 1.0, 2.0)
    kinds = ("viscous_coulomb", "hysteresis", "sensor_offset_gain", "payload") if quick else TWIN_EFFECT_TYPES
    cases = []
    for kind in kinds:
        if kind in LATER_TYPES:
            continue
        for m in (1.0,) if quick else mags:
            cases.append(BenchmarkCase(f"twin:{kind}@{m:g}", (kind,), m, int(rng.integers(1 << 30)), twin=True))
    cases += _later_cases(seed, "twin:", (0.5, 1.0) if quick else mags, True)
    library = [k for k in TWIN_EFFECT_TYPES if k not in ("payload", "torque_noise", "encoder_noise") + LATER_TYPES]
    for k in range(1 if quick else 4):
        present = tuple(sorted(rng.choice(library, size=k % 3, replace=False))) if k else ()
        cases.append(BenchmarkCase(f"twin:null#{k}" + (f"({'+'.join(present)})" if present else ""), (), 1.0,
                                   int(rng.integers(1 << 30)), modelled=present, twin=True))
    pairs = [("viscous_coulomb", "sensor_offset_gain"), ("hysteresis", "ripple"), ("payload", "viscous_coulomb"),
             ("lost_motion", "sensor_offset_gain")]
    for a, b in pairs[:1 if quick else len(pairs)]:
        cases.append(BenchmarkCase(f"twin:{a}+{b}", (a, b), 1.0, int(rng.integers(1 << 30)), twin=True))
    return cases


def select_cases(cases: list[BenchmarkCase], names: list[str] | None) -> list[BenchmarkCase]:
    """The cases named in ``names`` (all when ``None``), in the list's order; an unknown name is an error."""
    if names is None:
        return cases
    known = {c.name for c in cases}
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"unknown benchmark case(s) {bad}; this case list has: {', '.join(c.name for c in cases)}")
    return [c for c in cases if c.name in set(names)]
