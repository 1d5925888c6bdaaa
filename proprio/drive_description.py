"""The drive block of a robot description: what stands between the motors and the links of an arm, and what its τ is.

Most industrial arms report motor currents, not a link-side torque τ_J. Their drive torque τ_d = N·k_t·i sees
everything behind the motor. Per motor ``k`` (``n`` motors for ``n`` joints):

* ``gear_ratio`` ``N_k`` (signed) and ``torque_constant`` ``k_t,k`` [N·m/A at the motor] (used by importers that turn
  currents into motor torques);
* ``coupling`` ``R [n×n]``: motor angles from joint angles, ``q_motor = R q`` [rad]; joint-side drive torques from
  motor torques ``τ = Rᵀ τ_motor`` (power conservation). Default ``diag(N)``. Its diagonal must equal ``N``, so that
  the *normalised* coupling ``C = diag(N)⁻¹ R`` has a unit diagonal: ``v = C q̇`` is every motor's velocity in joint
  units (rad/s at the joint side). The TX40's wrist: ``R[5, 4] = N₆``, so ``v₆ = q̇₅ + q̇₆``.
* ``rotor_inertia`` ``I_a,k`` [kg·m²], the rotor's inertia reflected to the joint side (``N_k² J_rotor``);
  ``motor_friction``: viscous ``F_v,m`` [N·m·s/rad] and Coulomb ``F_c,m`` [N·m], reflected likewise (``N_k² b_m``,
  ``|N_k| f_m``), acting on the motor velocity ``v``;
* ``offset`` ``τ_0,j`` [N·m] per joint: a constant drive offset (current-sensor bias, gravity-compensation spring).

Together, at the joint side (the law, evaluated by :func:`proprio.identification.regressor.drive_columns`)::

    τ_drive = Cᵀ (I_a ⊙ C q̈ + F_v,m ⊙ C q̇ + F_c,m ⊙ sgn(C q̇)) + τ_0

``tau_kind`` says what the robot's τ channel is: ``link_sensor`` (a joint-torque sensor behind the gear: τ = τ_J,
the drive terms are invisible in it) or ``drive`` (τ = Rᵀ τ_motor, the drive terms are in it and are identified).
YAML (``drive:`` block of ``proprio-robot/v1`` and ``proprio-mdh/v1``)::

    drive:
      tau_kind: drive
      gear_ratio: [32, 32, 45, -48, 45, 32]
      torque_constant: [1, 1, 1, 1, 1, 1]          # optional, default 1 (the log holds motor torques)
      coupling: [[32, 0, ...], ..., [0, 0, 0, 0, 32, 32]]   # optional, default diag(gear_ratio)
      rotor_inertia: [0.362, 0.362, 0.0988, 0.0313, 0.0468, 0.0105]
      motor_friction: {viscous: [...], coulomb: [...]}      # optional, default 0
      offset: [...]                                         # optional, default 0
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["TAU_KINDS", "DriveDescription", "DriveDescriptionError", "drive_from_dict", "drive_from_urdf_element"]

TAU_KINDS = ("link_sensor", "drive")


class DriveDescriptionError(ValueError):
    """A ``drive`` block is malformed; the message names the offending field."""


@dataclass(frozen=True)
class DriveDescription:
    """The drive block of a :class:`~proprio.description.RobotDescription` (module docstring for the physics and
    units; every per-motor tuple has ``n`` entries, ``coupling`` is ``n`` rows of ``n``)."""
    tau_kind: str
    gear_ratio: tuple[float, ...]
    coupling: tuple[tuple[float, ...], ...]
    rotor_inertia: tuple[float, ...]
    torque_constant: tuple[float, ...]
    motor_viscous: tuple[float, ...]
    motor_coulomb: tuple[float, ...]
    offset: tuple[float, ...]

    @property
    def n(self) -> int:
        return len(self.gear_ratio)

    @property
    def in_tau(self) -> bool:
        """True when the τ channel is a drive torque, i.e. contains the drive terms (``tau_kind == 'drive'``)."""
        return self.tau_kind == "drive"

    @property
    def coupling_matrix(self) -> np.ndarray:
        """``R [n, n]``: ``q_motor = R q`` [rad of motor per rad of joint]."""
        return np.array(self.coupling, dtype=float)

    @property
    def normalized_coupling(self) -> np.ndarray:
        """``C = diag(N)⁻¹ R [n, n]`` (unit diagonal): motor velocities in joint units ``v = C q̇``."""
        return self.coupling_matrix / np.asarray(self.gear_ratio, dtype=float)[:, None]

    @property
    def coupled(self) -> bool:
        """True when some motor turns with more than one joint."""
        c = self.normalized_coupling
        return bool(np.any(np.abs(c - np.diag(np.diag(c))) > 0.0))

    def parameters(self) -> np.ndarray:
        """The identified drive parameters ``[I_a (n), F_v,m (n), F_c,m (n)]`` in the order of
        :func:`proprio.identification.regressor.drive_columns` (offsets are separate)."""
        return np.concatenate([self.rotor_inertia, self.motor_viscous, self.motor_coulomb])

    def with_parameters(self, p: np.ndarray, offset: np.ndarray | tuple[float, ...]) -> "DriveDescription":
        """A copy with ``I_a, F_v,m, F_c,m`` from ``p [3n]`` (order of :meth:`parameters`) and ``offset [n]`` [N·m]."""
        p, offset = np.asarray(p, dtype=float), np.asarray(offset, dtype=float)
        if p.shape != (3 * self.n,) or offset.shape != (self.n,):
            raise DriveDescriptionError(f"drive parameters: expected {3 * self.n} values and {self.n} offsets, got "
                                        f"{p.shape} and {offset.shape}")
        ia, fv, fc = (tuple(float(x) for x in p[k * self.n:(k + 1) * self.n]) for k in range(3))
        return DriveDescription(self.tau_kind, self.gear_ratio, self.coupling, ia, self.torque_constant, fv, fc,
                                tuple(float(x) for x in offset))

    def to_dict(self) -> dict[str, Any]:
        """The YAML mapping (inverse of :func:`drive_from_dict`)."""
        return {"tau_kind": self.tau_kind, "gear_ratio": list(self.gear_ratio),
                "coupling": [list(r) for r in self.coupling], "rotor_inertia": list(self.rotor_inertia),
                "torque_constant": list(self.torque_constant),
                "motor_friction": {"viscous": list(self.motor_viscous), "coulomb": list(self.motor_coulomb)},
                "offset": list(self.offset)}


def _vector(d: dict, key: str, where: str, n: int, default: float | None = None, nonneg: bool = False,
            nonzero: bool = False) -> tuple[float, ...]:
    if key not in d or d[key] is None:
        if default is None:
            raise DriveDescriptionError(f"{where}: missing field '{key}' ({n} numbers, one per motor)")
        return (float(default),) * n
    try:
        arr = np.asarray(d[key], dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise DriveDescriptionError(f"{where}.{key}: expected {n} numbers, got {d[key]!r}") from None
    if arr.size != n:
        raise DriveDescriptionError(f"{where}.{key}: expected {n} numbers (one per joint), got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise DriveDescriptionError(f"{where}.{key}: non-finite value in {d[key]!r}")
    if nonneg and np.any(arr < 0):
        raise DriveDescriptionError(f"{where}.{key}: must be >= 0, got {arr.tolist()}")
    if nonzero and np.any(arr == 0):
        raise DriveDescriptionError(f"{where}.{key}: must be nonzero, got {arr.tolist()}")
    return tuple(float(x) for x in arr)


def drive_from_dict(d: Any, n: int, where: str = "drive") -> DriveDescription:
    """Validate a ``drive`` mapping for an ``n``-joint arm (module docstring). Errors name the field."""
    if not isinstance(d, dict):
        raise DriveDescriptionError(f"{where}: expected a mapping, got {type(d).__name__}")
    known = {"tau_kind", "gear_ratio", "coupling", "rotor_inertia", "torque_constant", "motor_friction", "offset"}
    unknown = sorted(set(d) - known)
    if unknown:
        raise DriveDescriptionError(f"{where}: unknown field(s) {unknown}; known: {sorted(known)}")
    kind = d.get("tau_kind")
    if kind not in TAU_KINDS:
        raise DriveDescriptionError(f"{where}.tau_kind: must be one of {TAU_KINDS}, got {kind!r}")
    gear = _vector(d, "gear_ratio", where, n, default=1.0, nonzero=True)
    if "coupling" in d and d["coupling"] is not None:
        try:
            r = np.asarray(d["coupling"], dtype=float)
        except (TypeError, ValueError):
            raise DriveDescriptionError(f"{where}.coupling: expected {n} rows of {n} numbers") from None
        if r.shape != (n, n) or not np.all(np.isfinite(r)):
            raise DriveDescriptionError(f"{where}.coupling: expected {n} rows of {n} finite numbers, got shape "
                                        f"{r.shape}")
        if not np.allclose(np.diag(r), gear, rtol=1e-12, atol=0.0):
            raise DriveDescriptionError(f"{where}.coupling: its diagonal {np.diag(r).tolist()} must equal "
                                        f"gear_ratio {list(gear)} (q_motor = R q)")
        if abs(np.linalg.det(r / np.asarray(gear)[:, None])) < 1e-9:
            raise DriveDescriptionError(f"{where}.coupling: singular (joint angles cannot be recovered from the "
                                        "motor angles)")
    else:
        r = np.diag(gear)
    fr = d.get("motor_friction") or {}
    if not isinstance(fr, dict):
        raise DriveDescriptionError(f"{where}.motor_friction: expected a mapping {{viscous, coulomb}}")
    return DriveDescription(
        tau_kind=kind, gear_ratio=gear, coupling=tuple(tuple(float(x) for x in row) for row in r),
        rotor_inertia=_vector(d, "rotor_inertia", where, n, default=0.0, nonneg=True),
        torque_constant=_vector(d, "torque_constant", where, n, default=1.0, nonzero=True),
        motor_viscous=_vector(fr, "viscous", f"{where}.motor_friction", n, default=0.0, nonneg=True),
        motor_coulomb=_vector(fr, "coulomb", f"{where}.motor_friction", n, default=0.0, nonneg=True),
        offset=_vector(d, "offset", where, n, default=0.0))


def _local(tag: str) -> str:
    """An XML tag without its namespace (``{http://drake.mit.edu}rotor_inertia`` → ``rotor_inertia``)."""
    return tag.rsplit("}", 1)[-1]


def _child(el: Any, *names: str) -> Any:
    """The first child of ``el`` whose local tag is one of ``names`` (any namespace), else ``None``."""
    return next((c for c in el if _local(c.tag) in names), None)


def _number(el: Any, what: str, where: str) -> float:
    """The number of an element's ``value`` attribute or its text; errors name the element."""
    raw = el.get("value") if el.get("value") is not None else (el.text or "").strip()
    try:
        x = float(raw)
    except (TypeError, ValueError):
        raise DriveDescriptionError(f"{where}: {what}: {raw!r} is not a number") from None
    if not np.isfinite(x):
        raise DriveDescriptionError(f"{where}: {what}: {raw!r} is not finite")
    return x


def drive_from_urdf_element(root: Any, joint_names: list[str], where: str) -> DriveDescription | None:
    """A drive block from a URDF's transmissions and armature, ``None`` when every reduction is 1 and no rotor
    inertia is given (proprio's own URDF export writes unit transmissions). Read, per joint of the chain:

    * the gear ratio ``N``: a one-joint ``<transmission>``'s (anywhere in the file, also inside ROS 2's
      ``<ros2_control>``) ``mechanicalReduction`` (ROS 1: in ``<actuator>``, or the transmission itself in the old
      PR2 format) or ``mechanical_reduction`` (ROS 2: in ``<joint>`` or ``<actuator>``), or Drake's
      ``<actuator><drake:gear_ratio value>``;
    * the reflected rotor inertia ``I_a`` [kg·m², joint side]: Drake's ``<actuator><drake:rotor_inertia value>``
      (the rotor's own, motor side: ``I_a = N² J_rotor``, as Drake reflects it) or ``<joint><dynamics armature>``
      (already joint side, MuJoCo's meaning; it wins when both are given).

    A transmission with several joints or actuators (differential, four-bar) is not read (a ``UserWarning`` names
    it: give ``drive.coupling`` in a robot YAML). A URDF does not say what the τ channel is: ``tau_kind`` is
    ``link_sensor`` (the drive terms simulated, not identified); a drive-torque arm says ``tau_kind: drive`` in its
    YAML."""
    import warnings

    n = len(joint_names)
    gear, arm, found = [1.0] * n, [0.0] * n, False
    index = {name: k for k, name in enumerate(joint_names)}
    for tr in root.iter("transmission"):
        joints = [c for c in tr if _local(c.tag) == "joint"]
        actuators = [c for c in tr if _local(c.tag) == "actuator"]
        names = [j.get("name") for j in joints]
        if not any(nm in index for nm in names):
            continue
        label = f"{where}: transmission {tr.get('name')!r}"
        if len(joints) > 1 or len(actuators) > 1:
            warnings.warn(f"{label} couples joints {names} (several joints/actuators): not read; give the drive's "
                          "'coupling' (and gear_ratio) in a robot YAML", UserWarning, stacklevel=2)
            continue
        k, joint, act = index[names[0]], joints[0], actuators[0] if actuators else None
        red = _child(joint, "mechanical_reduction")
        if red is None and act is not None:
            red = _child(act, "mechanicalReduction", "mechanical_reduction", "gear_ratio")
        if red is None:
            red = _child(tr, "mechanicalReduction")
        if red is not None:
            gear[k] = _number(red, f"gear ratio of joint {names[0]!r}", label)
            if gear[k] == 0.0:
                raise DriveDescriptionError(f"{label}: gear ratio of joint {names[0]!r} is 0")
        rotor = _child(act, "rotor_inertia") if act is not None else None
        if rotor is not None:
            arm[k] = gear[k] ** 2 * _number(rotor, f"rotor inertia of joint {names[0]!r}", label)
        found = found or gear[k] != 1.0 or arm[k] != 0.0
    for el in root.findall("joint"):
        dyn = el.find("dynamics")
        if el.get("name") in index and dyn is not None and dyn.get("armature") is not None:
            k, raw = index[el.get("name")], dyn.get("armature")
            try:
                arm[k] = float(raw)
            except ValueError:
                raise DriveDescriptionError(f"{where}: joint {el.get('name')!r} <dynamics armature={raw!r}>: not a "
                                            "number") from None
            found = found or arm[k] != 0.0
    if not found:
        return None
    return drive_from_dict({"tau_kind": "link_sensor", "gear_ratio": gear, "rotor_inertia": arm}, n, where)
