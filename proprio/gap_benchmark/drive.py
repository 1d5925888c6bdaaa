"""The gap benchmark's family of drive-torque arms (``proprio gap-benchmark --drive``): the effects real drives have,
withheld from the model of an arm whose τ is its drives' torque (no joint-torque sensor), recorded through the twin.

**The arm.** The shipped ``iiwa14_twin`` (its controller, its link friction as the ``viscous_coulomb`` effect) made a
drive-torque arm: its robot gets a ``drive`` block (:mod:`proprio.drive_description`) with ``tau_kind: drive``, gear
ratio 100 per joint and the twin's motor side as reflected rotor inertia and motor friction (each drawn at 0.7–1.3 ×
the shipped values), constant drive offsets of 0.2–0.9 N·m with random signs, and white noise of 0.1–0.3 N·m on the
drive torque (current noise). The twin's drive senses ``τ = τ_rbd + I_a q̈ + τ_f,link + τ_f,m + τ_0``
(:class:`proprio.systems.joint_drive.JointDrive`). The drives are uncoupled except in the ``coupled_motor_friction``
cases, whose last motor turns with the last two joints (``q_m7 = N (q6 + q7)``, as the TX40's motor 6 with joints 5
and 6; its reflected inertia ``Cᵀ diag(I_a) C`` couples the two joints in the plant). An uncoupled motor's friction
is told from the link friction only because the model has that
(:func:`proprio.diagnosis.candidates.registry.candidate_set`).

**Withheld** (:data:`DRIVE_TYPES`, magnitude ``m``): ``motor_friction`` and ``drive_offset`` — the model's drive
block has ``(1 − m)`` × the arm's value; ``coupled_motor_friction`` — the same for the shared motor's friction only
(the other motors' is known); ``rotor_inertia`` — the arm's is ``(1 + m)`` × the model's (the gearbox and
brake inertia a motor datasheet leaves out; the plant never loses the model's part, which keeps the explicit friction
stable at 1 ms in the floor's data too); ``presliding`` — the arm's drives add pre-sliding friction
(:class:`proprio.effects.PreSliding`, level ``m`` × 0.3–0.8 N·m, turning over within 0.2–1° of travel), applied by
the twin's drive per step; ``load_friction`` — the arm's gears add load-dependent Coulomb friction
(:class:`proprio.effects.LoadFriction`, ``m`` × (0.03–0.15 N·m + 1–3 % of the joint's transmitted torque)), applied
by the twin's drive per step on the joint's own torque (also on the coupled joints). Null cases: the model has everything. Each at 100 Hz (host stamps with σ = 1 ms jitter,
0.2 % lost samples) and at 1 kHz (σ = 0.1 ms, 0.2 %) — :data:`DRIVE_LOGGERS`. The Recordings say
``meta.tau_kind: drive``. Scored by :func:`proprio.gap_benchmark.run.summarise` like every single-effect case (top-1
is the withheld effect; a null case names nothing), and as its own family line.
"""
from __future__ import annotations

import dataclasses
import zlib
from typing import Any

import numpy as np

from proprio.gap_benchmark.recordings import ENCODER, CaseData, twin_recordings
from proprio.gap_benchmark.cases import BenchmarkCase, _draw
from proprio.drive_description import drive_from_dict
from proprio.effects import EFFECTS, LoadFriction, PreSliding

__all__ = ["DRIVE_TYPES", "SHARED_MOTOR", "DRIVE_LOGGERS", "drive_cases", "drive_case_config", "generate_drive_case_data"]

DRIVE_TYPES = ("rotor_inertia", "presliding", "motor_friction", "coupled_motor_friction", "drive_offset",
               "load_friction")
SHARED_MOTOR = 6
"""The motor of the ``coupled_motor_friction`` cases that turns with joints ``SHARED_MOTOR − 1`` and ``SHARED_MOTOR``
(0-based): the iiwa's last motor with its last two joints."""
GEAR_RATIO = 100.0
DRIVE_LOGGERS: dict[float, tuple[tuple[str, Any], ...]] = {
    100.0: (("rate_hz", 100.0), ("stamp_jitter_ms", 1.0), ("dropout_prob", 0.002)),
    1000.0: (("rate_hz", 1000.0), ("stamp_jitter_ms", 0.1), ("dropout_prob", 0.002)),
}
"""Robot-like loggers of the family: a current-sensed arm's host at 100 Hz, a 1 kHz real-time interface."""


def drive_cases(quick: bool = False, seed: int = 0) -> list[BenchmarkCase]:
    """The family: every :data:`DRIVE_TYPES` at magnitudes 0.5 and 1 (quick: 1) and 2 null cases (quick: 1), at 100 Hz
    and 1 kHz; named ``drive:<kind>@<m>/<rate>Hz`` and ``drive:null#<k>/<rate>Hz``. Each case's seed is drawn from its
    name, so a kind added later moves no other case."""
    cases = []
    for rate, logger in DRIVE_LOGGERS.items():
        for kind in DRIVE_TYPES:
            for m in (0.5, 1.0) if not quick or kind == "load_friction" else (1.0,):
                name = f"drive:{kind}@{m:g}/{rate:g}Hz"
                cases.append(BenchmarkCase(name, (kind,), m, _case_seed(name, seed), twin=True, logger=logger))
        for k in range(1 if quick else 2):
            name = f"drive:null#{k}/{rate:g}Hz"
            cases.append(BenchmarkCase(name, (), 1.0, _case_seed(name, seed), twin=True, logger=logger))
    return cases


def _case_seed(name: str, seed: int) -> int:
    """A case's seed from its name and the family's ``seed``."""
    return int(np.random.default_rng([seed, 22, zlib.crc32(name.encode())]).integers(1 << 30))


def drive_case_config(case: BenchmarkCase, omit_withheld: bool = False) -> tuple[Any, Any, dict[str, Any]]:
    """``(TwinConfig of the arm, the model's robot description, the model's friction parameters)`` of a case (module
    docstring); ``omit_withheld``: the arm as the model has it (what a model with the withheld effect would leave)."""
    from proprio.diagrams.twin_config import load_twin_config
    from proprio.systems.joint_drive import coupling_from_description, motor_from_description

    bad = sorted(set(case.withheld) - set(DRIVE_TYPES))
    if bad:
        raise ValueError(f"drive case {case.name!r}: {bad} are not drive-family effects {list(DRIVE_TYPES)}")
    base = load_twin_config("iiwa14_twin").with_payload(None).with_logger(**dict(case.logger))
    n = base.robot.n
    rng = np.random.default_rng(case.seed)
    u = lambda a, b: rng.uniform(a, b, n)  # noqa: E731
    motor, link = base.motor, base.effect("viscous_coulomb")
    arm = {"rotor_inertia": motor.motor_inertia * u(0.7, 1.3), "viscous": motor.motor_viscous * u(0.7, 1.3),
           "coulomb": motor.motor_coulomb * u(0.7, 1.3), "offset": u(0.2, 0.9) * rng.choice([-1.0, 1.0], n)}
    presliding = _draw("presliding", n, case.magnitude, rng)
    load = _draw("load_friction", n, case.magnitude, np.random.default_rng([case.seed, 39]))   # own stream
    noise = u(0.1, 0.3)
    short = {"rotor_inertia": ("rotor_inertia",), "motor_friction": ("viscous", "coulomb"),
             "coupled_motor_friction": ("viscous", "coulomb"), "drive_offset": ("offset",)}
    coupled = "coupled_motor_friction" in case.withheld
    model = dict(arm)
    for kind in case.withheld:
        which = np.arange(n) == SHARED_MOTOR if kind == "coupled_motor_friction" else np.ones(n, bool)
        for key in short.get(kind, ()):
            model[key] = np.where(which, (1.0 - case.magnitude) * arm[key], arm[key])
    if "rotor_inertia" in case.withheld:       # the plant keeps the model's rotor inertia (explicit friction at 1 ms)
        model["rotor_inertia"] = arm["rotor_inertia"]
        arm["rotor_inertia"] = (1.0 + case.magnitude) * arm["rotor_inertia"]
    if omit_withheld:
        arm = model

    def robot_with(p: dict[str, np.ndarray]):
        coupling = GEAR_RATIO * np.eye(n)
        if coupled:
            coupling[SHARED_MOTOR, SHARED_MOTOR - 1] = GEAR_RATIO
        block = {"tau_kind": "drive", "gear_ratio": [GEAR_RATIO] * n, "coupling": coupling.tolist(),
                 "rotor_inertia": p["rotor_inertia"].tolist(),
                 "motor_friction": {"viscous": p["viscous"].tolist(), "coulomb": p["coulomb"].tolist()},
                 "offset": p["offset"].tolist()}
        return dataclasses.replace(base.robot.without_friction(), drive=drive_from_dict(block, n))

    robot = robot_with(arm)
    effects = [link, EFFECTS["torque_noise"](n, std=noise), EFFECTS["encoder_noise"](n, **ENCODER)]
    if "presliding" in case.withheld and not omit_withheld:
        effects.append(PreSliding(n, **presliding))
    if "load_friction" in case.withheld and not omit_withheld:
        effects.append(LoadFriction(n, **load))
    config = dataclasses.replace(base, robot=robot, motor=motor_from_description(robot),
                                 motor_coupling=coupling_from_description(robot), effects=effects,
                                 name="iiwa14_drive_arm")
    params = {"viscous_coulomb": {k: v for k, v in link.params().items()}, "torque_noise": {"std": noise},
              "encoder_noise": {k: np.full(n, v) for k, v in ENCODER.items()}}
    return config, robot_with(model), params


def generate_drive_case_data(case: BenchmarkCase, omit_withheld: bool = False) -> CaseData:
    """The case's 2 training and 1 held-out recordings through the drive arm's twin (:func:`drive_case_config`),
    ``meta.tau_kind: drive``; the model: the case's robot description (its drive block short of the withheld terms)
    with the link friction, torque and encoder noise the data were made with."""
    config, model_robot, params = drive_case_config(case, omit_withheld)
    recs = twin_recordings(case, [config] * 3, meta={"tau_kind": "drive"})
    return CaseData(model_robot, ("viscous_coulomb", "torque_noise", "encoder_noise"), params, recs[:2], recs[2:])
