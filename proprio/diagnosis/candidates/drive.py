"""The drive candidates of the torque gap: the drive terms a drive-torque arm's model may lack
(:class:`DriveCandidate`), what the model's τ is (:func:`tau_kind`) and which candidates each kind of τ can show."""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from proprio.description import RobotDescription
from proprio.diagnosis.candidates.base import Candidate
from proprio.diagnosis.data import DiagnosisError, GapData
from proprio.identification.regressor import drive_columns, drive_identified

__all__ = ["DriveCandidate", "DRIVE_CANDIDATES", "GAUGE_ONLY", "DRIVE_ONLY", "tau_kind"]


DRIVE_CANDIDATES = ("rotor_inertia", "motor_friction", "drive_offset")
"""The drive's terms the model may lack, as candidates (:class:`DriveCandidate`)."""

GAUGE_ONLY = ("hysteresis", "lost_motion", "ripple", "sensor_offset")
"""Candidates of a joint-torque sensor's strain gauge (its loop, its lost motion, its ripple, its zero): not
candidates when τ is a drive torque (current × torque constant × gear ratio has no gauge; a drive's constant bias is
``drive_offset``). A gain error stays a candidate for both kinds (a drive torque's is a torque-constant error)."""

DRIVE_ONLY = DRIVE_CANDIDATES + ("presliding",)
"""Candidates only a drive torque sees: rotor inertia, the motor's friction and the drive's offsets sit before a
link-side torque sensor, and pre-sliding friction is, in τ, the Dahl law of the gauge's hysteresis (one law, the
same function of the reversal travel: :mod:`proprio.effects.dahl`), which a link sensor's diagnosis names
hysteresis."""


def tau_kind(robot: RobotDescription) -> str:
    """What the model's τ channel is: ``drive`` when the description's drive block says ``tau_kind: drive`` (its
    drive terms are in the model), else ``link_sensor`` (:mod:`proprio.drive_description`)."""
    return "drive" if drive_identified(robot) else "link_sensor"


class DriveCandidate(Candidate):
    """A drive term a drive-torque arm's model lacks (``robot.drive.tau_kind == 'drive'``), linear in its
    parameters, on the law of :func:`proprio.identification.regressor.drive_columns` (the identification's, with the
    description's coupling ``C``): ``rotor_inertia`` ``Cᵀ(I_a ⊙ C q̈)`` (I_a [kg·m²] per motor), ``motor_friction``
    ``Cᵀ(F_v,m ⊙ C q̇ + F_c,m ⊙ sgn_s(C q̇))`` ([N·m·s/rad], [N·m] per motor: a motor shared by coupled joints brakes
    each of them through Cᵀ) and ``drive_offset`` τ_0 [N·m] per joint. The fit is the part the model lacks: the
    patch adds it to the description's drive block. ``motors`` (0-based) restricts the motor terms to those motors
    (default all): an uncoupled motor's friction is the joint's own (:func:`candidate_set`)."""
    place = "motor"

    def __init__(self, robot: RobotDescription, group: str, motors: Sequence[int] | None = None):
        if group not in DRIVE_CANDIDATES:
            raise DiagnosisError(f"drive candidate {group!r}: must be one of {DRIVE_CANDIDATES}")
        if not drive_identified(robot):
            raise DiagnosisError(f"drive candidate {group}: the robot description {robot.name!r} has no drive block "
                                 "with tau_kind: drive")
        self.robot, self.name, n = robot, group, robot.n
        self._motors = np.arange(n) if motors is None else np.asarray(motors, dtype=int)
        groups = {"rotor_inertia": (0,), "motor_friction": (1, 2)}.get(group)
        self._cols = None if groups is None else np.concatenate([g * n + self._motors for g in groups])

    def param_names(self) -> list[str]:
        keys = {"rotor_inertia": ("I_a",), "motor_friction": ("F_v,m", "F_c,m"), "drive_offset": ("offset",)}
        index = range(self.robot.n) if self._cols is None else self._motors
        return [f"{k}[{j + 1}]" for k in keys[self.name] for j in index]

    def design(self, data: GapData) -> np.ndarray:
        if self._cols is None:
            return data.stack([np.broadcast_to(np.eye(s.n), s.q.shape + (s.n,)) for s in data.signals])
        drive = self.robot.drive
        return data.stack([np.moveaxis(drive_columns(drive, s.qd.T, s.qdd.T, None), -1, 0)[..., self._cols]
                           for s in data.signals])

    def joint_of_param(self, n: int) -> np.ndarray:
        if self._cols is None:
            return np.arange(n)
        if not self.robot.drive.coupled:
            return np.tile(self._motors, self.n_params // len(self._motors))
        return -np.ones(self.n_params, dtype=int)

    def patch(self, theta: np.ndarray) -> dict[str, Any] | None:
        """``{"robot": <description mapping>}`` with the fit added to its drive block's parameters."""
        drive = self.robot.drive
        theta = np.asarray(theta, dtype=float)
        p, offset = drive.parameters(), np.asarray(drive.offset, dtype=float)
        if self._cols is None:
            offset = offset + theta
        else:
            p[self._cols] += theta
        lo = np.zeros_like(p)
        self.patch_note = ""
        if np.any(p < lo):
            self.patch_note = (f"{self.name}: a fitted drive parameter below zero (rotor inertia and motor friction "
                               f"are not negative), clipped to 0 in the patch")
            p = np.maximum(p, lo)
        desc = replace(self.robot, drive=drive.with_parameters(p, offset)).to_dict()
        desc["name"] = self.robot.name
        return {"robot": desc}
