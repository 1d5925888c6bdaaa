"""Robot descriptions: the YAML robot format, its validating loader, and imports from MDH tables and URDF.

A :class:`RobotDescription` is a serial chain of revolute joints. Frames follow URDF semantics:

* ``T_parent_joint = Translation(origin_xyz) · Rz(yaw) Ry(pitch) Rx(roll)`` with ``origin_rpy = [roll, pitch, yaw]``;
  the child link frame is the joint frame rotated by ``q`` about the unit ``axis`` (expressed in the joint frame).
* Link inertials: ``mass`` [kg], ``com_xyz`` [m] in the link frame, ``inertia_com`` [kg·m²] about the CoM in a frame
  rotated by ``com_rpy`` from the link frame, stored as ``(ixx, iyy, izz, ixy, ixz, iyz)``.
* Angles are radians everywhere except where a key ends in ``_deg`` (converted here, at the boundary).

The YAML layout (``format: proprio-robot/v1``) is documented in ``README.md`` and is a superset of the
``robot-numbers/v1`` layout of ``../shared/data/kuka_lwr4/robot.yaml``, so that file loads directly.
"""
from __future__ import annotations

import dataclasses
import difflib
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from proprio.drive_description import (DriveDescription, DriveDescriptionError, drive_from_dict,
                                      drive_from_urdf_element)

__all__ = [
    "CollisionShape", "Joint", "Link", "EndEffector", "RobotDescription", "DescriptionError",
    "load_robot", "robot_from_dict", "robot_from_mdh", "robot_from_urdf", "builtin_robots", "rpy_to_matrix",
    "check_keys",
]

INERTIA_KEYS = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")


class DescriptionError(ValueError):
    """A robot description is malformed; the message names the offending field."""


def rpy_to_matrix(rpy: np.ndarray | list[float]) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw [rad] to a rotation matrix ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


@dataclass(frozen=True)
class CollisionShape:
    """A simple collision primitive in its link frame: ``sphere`` (radius), ``cylinder`` (radius, length along
    the local z axis) or ``box`` (size = full extents [m])."""
    shape: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    length: float = 0.0
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Link:
    """A rigid body: mass [kg], CoM [m] in the link frame, rotational inertia about the CoM [kg·m²]."""
    name: str
    mass: float
    com_xyz: tuple[float, float, float]
    inertia_com: tuple[float, float, float, float, float, float]  # ixx, iyy, izz, ixy, ixz, iyz
    com_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    collision: tuple[CollisionShape, ...] = ()

    def inertia_matrix_link(self) -> np.ndarray:
        """3×3 inertia about the CoM, expressed in the link frame (rotated from the ``com_rpy`` frame)."""
        ixx, iyy, izz, ixy, ixz, iyz = self.inertia_com
        i_c = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        r = rpy_to_matrix(self.com_rpy)
        return r @ i_c @ r.T


@dataclass(frozen=True)
class Joint:
    """A revolute joint. Limits in rad, rad/s, rad/s² and N·m."""
    name: str
    parent: str
    child: str
    origin_xyz: tuple[float, float, float]
    origin_rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    lower: float
    upper: float
    velocity: float
    effort: float
    acceleration: float = math.inf


@dataclass(frozen=True)
class EndEffector:
    """The flange / end-effector frame, fixed to ``parent`` at ``xyz`` [m], ``rpy`` [rad]."""
    parent: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "flange"


@dataclass(frozen=True)
class RobotDescription:
    """A serial revolute arm. ``links[i]`` is the body moved by ``joints[i]``; ``base`` is welded to the world at
    ``world_to_base_xyz/rpy``. Friction (optional, per joint): viscous [N·m·s/rad] and Coulomb [N·m]."""
    name: str
    base: Link
    joints: tuple[Joint, ...]
    links: tuple[Link, ...]
    end_effector: EndEffector
    world_to_base_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    world_to_base_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    friction_viscous: tuple[float, ...] | None = None
    friction_coulomb: tuple[float, ...] | None = None
    provenance: str = ""
    drive: DriveDescription | None = None         # motors, gears, coupling, what τ is (proprio.drive_description)

    # ---- convenient array views -------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.joints)

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def lower(self) -> np.ndarray:
        """Lower position limits [rad]."""
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        """Upper position limits [rad]."""
        return np.array([j.upper for j in self.joints])

    @property
    def velocity_limits(self) -> np.ndarray:
        """Symmetric velocity limits [rad/s]."""
        return np.array([j.velocity for j in self.joints])

    @property
    def acceleration_limits(self) -> np.ndarray:
        """Symmetric acceleration limits [rad/s²] (``inf`` where the description gives none)."""
        return np.array([j.acceleration for j in self.joints])

    @property
    def effort_limits(self) -> np.ndarray:
        """Symmetric torque limits [N·m]."""
        return np.array([j.effort for j in self.joints])

    @property
    def has_friction(self) -> bool:
        return self.friction_viscous is not None

    def with_inertials(self, links: list[Link] | tuple[Link, ...]) -> "RobotDescription":
        """A copy with other link inertials (same kinematics), e.g. an identified parameter set."""
        if len(links) != self.n:
            raise DescriptionError(f"with_inertials: expected {self.n} links, got {len(links)}")
        return dataclasses.replace(self, links=tuple(links))

    def without_friction(self) -> "RobotDescription":
        return dataclasses.replace(self, friction_viscous=None, friction_coulomb=None)

    def to_dict(self) -> dict[str, Any]:
        """The ``proprio-robot/v1`` YAML mapping of this description (inverse of :func:`robot_from_dict`)."""
        def link_dict(link: Link) -> dict[str, Any]:
            d: dict[str, Any] = {
                "name": link.name, "mass": link.mass, "com_xyz": list(link.com_xyz), "com_rpy": list(link.com_rpy),
                "inertia_com": dict(zip(INERTIA_KEYS, link.inertia_com)),
            }
            if link.collision:
                d["collision"] = [_shape_dict(s) for s in link.collision]
            return d

        out: dict[str, Any] = {
            "format": "proprio-robot/v1", "name": self.name, "provenance": self.provenance,
            "gravity_world": list(self.gravity),
            "base": {"world_to_base_link": {"xyz": list(self.world_to_base_xyz), "rpy": list(self.world_to_base_rpy)},
                     "base_link": link_dict(self.base)},
            "joints": [{
                "name": j.name, "parent": j.parent, "child": j.child, "origin_xyz": list(j.origin_xyz),
                "origin_rpy": list(j.origin_rpy), "axis": list(j.axis),
                "limits": {"lower": j.lower, "upper": j.upper, "velocity": j.velocity, "effort": j.effort,
                           **({"acceleration": j.acceleration} if math.isfinite(j.acceleration) else {})},
            } for j in self.joints],
            "links": [link_dict(lk) for lk in self.links],
            "end_effector": {"name": self.end_effector.name, "parent": self.end_effector.parent,
                             "xyz": list(self.end_effector.xyz), "rpy": list(self.end_effector.rpy)},
        }
        if self.has_friction:
            out["friction"] = {"viscous": list(self.friction_viscous), "coulomb": list(self.friction_coulomb)}
        if self.drive is not None:
            out["drive"] = self.drive.to_dict()
        return out


def _shape_dict(s: CollisionShape) -> dict[str, Any]:
    d: dict[str, Any] = {"shape": s.shape, "xyz": list(s.xyz), "rpy": list(s.rpy)}
    if s.shape in ("sphere", "cylinder"):
        d["radius"] = s.radius
    if s.shape == "cylinder":
        d["length"] = s.length
    if s.shape == "box":
        d["size"] = list(s.size)
    return d


# ---- validation helpers ---------------------------------------------------------------------------------

def check_keys(d: dict, allowed: tuple[str, ...] | frozenset[str], where: str,
               ignored: tuple[str, ...] | frozenset[str] = ()) -> None:
    """Refuse a key of mapping ``d`` that is neither ``allowed`` nor in the explicit ``ignored`` list (documentation
    keys a format carries, e.g. ``note``); the error names the key path and the nearest valid key."""
    for key in d:
        if key in allowed or key in ignored:
            continue
        near = difflib.get_close_matches(str(key), [*allowed], n=1, cutoff=0.5)
        hint = f"; did you mean '{near[0]}'?" if near else f" (valid: {', '.join(allowed)})"
        raise DescriptionError(f"{where}: unknown key '{key}'{hint}")


def _vec(d: dict, key: str, where: str, size: int = 3, default: Any = None) -> tuple[float, ...]:
    if key not in d:
        if default is not None:
            return tuple(default)
        raise DescriptionError(f"{where}: missing field '{key}'")
    v = d[key]
    try:
        arr = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DescriptionError(f"{where}.{key}: expected {size} numbers, got {v!r}") from exc
    if arr.size != size:
        raise DescriptionError(f"{where}.{key}: expected {size} numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise DescriptionError(f"{where}.{key}: non-finite value in {v!r}")
    return tuple(float(x) for x in arr)


def _num(d: dict, key: str, where: str, default: float | None = None, positive: bool = False,
         nonneg: bool = False) -> float:
    if key not in d:
        if default is not None:
            return default
        raise DescriptionError(f"{where}: missing field '{key}'")
    try:
        x = float(d[key])
    except (TypeError, ValueError) as exc:
        raise DescriptionError(f"{where}.{key}: expected a number, got {d[key]!r}") from exc
    if math.isnan(x):
        raise DescriptionError(f"{where}.{key}: NaN")
    if positive and not x > 0:
        raise DescriptionError(f"{where}.{key}: must be > 0, got {x}")
    if nonneg and x < 0:
        raise DescriptionError(f"{where}.{key}: must be >= 0, got {x}")
    return x


def _angle(d: dict, key: str, where: str, default: float | None = None) -> float:
    """Read an angle in rad, or ``key_deg`` in degrees (converted); giving both is an error."""
    if key in d and f"{key}_deg" in d:
        raise DescriptionError(f"{where}: both '{key}' and '{key}_deg' given; keep one")
    if f"{key}_deg" in d:
        return math.radians(_num(d, f"{key}_deg", where))
    return _num(d, key, where, default)


def _parse_inertia(v: Any, where: str) -> tuple[float, ...]:
    if isinstance(v, dict):
        missing = [k for k in INERTIA_KEYS[:3] if k not in v]
        if missing:
            raise DescriptionError(f"{where}.inertia_com: missing {missing}")
        vals = tuple(_num(v, k, f"{where}.inertia_com", default=0.0) for k in INERTIA_KEYS)
    else:
        vals = _vec({"inertia_com": v}, "inertia_com", where, size=6)
    return vals


def _parse_link(d: dict, where: str) -> Link:
    if not isinstance(d, dict):
        raise DescriptionError(f"{where}: expected a mapping, got {type(d).__name__}")
    name = str(d.get("name", "")) or None
    if name is None:
        raise DescriptionError(f"{where}: missing field 'name'")
    where = f"{where}({name})"
    mass = _num(d, "mass", where, nonneg=True)
    com = _vec(d, "com_xyz" if "com_xyz" in d else "com", where)
    inertia_key = "inertia_com" if "inertia_com" in d else "inertia"
    if inertia_key not in d:
        raise DescriptionError(f"{where}: missing field 'inertia_com'")
    inertia = _parse_inertia(d[inertia_key], where)
    com_rpy = _vec(d, "com_rpy", where, default=(0.0, 0.0, 0.0))
    shapes = tuple(_parse_shape(s, f"{where}.collision[{k}]") for k, s in enumerate(d.get("collision") or []))
    link = Link(name=name, mass=mass, com_xyz=com, inertia_com=inertia, com_rpy=com_rpy, collision=shapes)
    _check_inertia(link, where)
    return link


def _check_inertia(link: Link, where: str) -> None:
    i = link.inertia_matrix_link()
    eig = np.linalg.eigvalsh(i)
    tol = 1e-12
    if eig[0] < -tol:
        raise DescriptionError(f"{where}.inertia_com: not positive semi-definite (eigenvalues {eig})")
    # triangle inequality of principal moments
    a, b, c = eig
    if a + b < c * (1 - 1e-9):
        raise DescriptionError(f"{where}.inertia_com: principal moments {eig} violate the triangle inequality")


def _parse_shape(d: dict, where: str) -> CollisionShape:
    if not isinstance(d, dict) or "shape" not in d:
        raise DescriptionError(f"{where}: expected a mapping with 'shape'")
    shape = d["shape"]
    xyz = _vec(d, "xyz", where, default=(0, 0, 0))
    rpy = _vec(d, "rpy", where, default=(0, 0, 0))
    if shape == "sphere":
        return CollisionShape("sphere", xyz, rpy, radius=_num(d, "radius", where, positive=True))
    if shape == "cylinder":
        return CollisionShape("cylinder", xyz, rpy, radius=_num(d, "radius", where, positive=True),
                              length=_num(d, "length", where, positive=True))
    if shape == "box":
        size = _vec(d, "size", where)
        if min(size) <= 0:
            raise DescriptionError(f"{where}.size: extents must be > 0, got {size}")
        return CollisionShape("box", xyz, rpy, size=size)
    raise DescriptionError(f"{where}.shape: unknown shape {shape!r} (sphere, cylinder, box)")


def _parse_joint(d: dict, where: str) -> Joint:
    if not isinstance(d, dict):
        raise DescriptionError(f"{where}: expected a mapping")
    for key in ("name", "parent", "child"):
        if key not in d:
            raise DescriptionError(f"{where}: missing field '{key}'")
    where = f"{where}({d['name']})"
    axis = np.array(_vec(d, "axis", where))
    norm = np.linalg.norm(axis)
    if not abs(norm - 1.0) < 1e-6:
        raise DescriptionError(f"{where}.axis: must be a unit vector, got {axis.tolist()} (norm {norm:.6g})")
    lim = d.get("limits")
    if not isinstance(lim, dict):
        raise DescriptionError(f"{where}: missing mapping 'limits' (lower, upper, velocity, effort)")
    lw = f"{where}.limits"
    lower, upper = _angle(lim, "lower", lw), _angle(lim, "upper", lw)
    if not lower < upper:
        raise DescriptionError(f"{lw}: lower ({lower}) must be < upper ({upper})")
    if max(abs(lower), abs(upper)) > 2 * math.pi + 1e-9:
        raise DescriptionError(f"{lw}: |limit| > 2π rad — were degrees given without the '_deg' suffix?")
    vel = _angle(lim, "velocity", lw)
    if not vel > 0:
        raise DescriptionError(f"{lw}.velocity: must be > 0, got {vel}")
    if vel > 20.0:
        raise DescriptionError(f"{lw}.velocity: {vel} rad/s is implausible for a revolute joint — were deg/s given "
                               "without the '_deg' suffix?")
    acc = _num(lim, "acceleration", lw, default=math.inf, positive=True)
    return Joint(name=str(d["name"]), parent=str(d["parent"]), child=str(d["child"]),
                 origin_xyz=_vec(d, "origin_xyz", where), origin_rpy=_vec(d, "origin_rpy", where, default=(0, 0, 0)),
                 axis=tuple(float(a) for a in axis / norm), lower=lower, upper=upper, velocity=vel,
                 effort=_num(lim, "effort", lw, positive=True), acceleration=acc)


def robot_from_dict(data: dict[str, Any], source: str = "<dict>") -> RobotDescription:
    """Validate a parsed YAML mapping (``proprio-robot/v1``, ``robot-numbers/v1`` or ``proprio-mdh/v1``)."""
    if not isinstance(data, dict):
        raise DescriptionError(f"{source}: top level must be a mapping")
    fmt = str(data.get("format", "proprio-robot/v1"))
    if fmt.startswith("proprio-mdh"):
        return _robot_from_mdh_dict(data, source)
    name = str(data.get("name", Path(source).stem))
    base = data.get("base") or {}
    pose = (base.get("world_to_base_link") or {}) if isinstance(base, dict) else None
    if not isinstance(base, dict) or not isinstance(pose, dict):
        raise DescriptionError(f"{source}:base: expected a mapping with 'world_to_base_link' {{xyz, rpy}} and "
                               "'base_link'")
    base_link = _parse_link(base["base_link"], f"{source}:base.base_link") if "base_link" in base else \
        Link("base", 0.0, (0.0, 0.0, 0.0), (0.0,) * 6)
    if "joints" not in data or "links" not in data:
        raise DescriptionError(f"{source}: needs 'joints' and 'links' lists")
    joints = tuple(_parse_joint(j, f"{source}:joints[{k}]") for k, j in enumerate(data["joints"]))
    links = tuple(_parse_link(lk, f"{source}:links[{k}]") for k, lk in enumerate(data["links"]))
    if len(joints) != len(links) or not joints:
        raise DescriptionError(f"{source}: {len(joints)} joints but {len(links)} links (need one link per joint)")
    # serial-chain check
    prev = base_link.name
    for k, (j, lk) in enumerate(zip(joints, links)):
        if j.parent != prev:
            raise DescriptionError(f"{source}:joints[{k}]({j.name}).parent is '{j.parent}', expected '{prev}' "
                                   "(only serial chains are supported)")
        if j.child != lk.name:
            raise DescriptionError(f"{source}:joints[{k}]({j.name}).child is '{j.child}' but links[{k}] is "
                                   f"'{lk.name}'")
        prev = lk.name
    ee = data.get("end_effector") or {"parent": links[-1].name}
    if not isinstance(ee, dict):
        raise DescriptionError(f"{source}:end_effector: expected a mapping {{name, parent, xyz, rpy}}, got {ee!r}")
    ee_obj = EndEffector(parent=str(ee.get("parent", links[-1].name)), xyz=_vec(ee, "xyz", f"{source}:end_effector",
                         default=(0, 0, 0)), rpy=_vec(ee, "rpy", f"{source}:end_effector", default=(0, 0, 0)),
                         name=str(ee.get("name", "flange")))
    if ee_obj.parent != links[-1].name:
        raise DescriptionError(f"{source}:end_effector.parent must be the last link '{links[-1].name}'")
    fv = fc = None
    fr = data.get("friction")
    if fr is not None:
        fv = _vec(fr, "viscous", f"{source}:friction", size=len(joints))
        fc = _vec(fr, "coulomb", f"{source}:friction", size=len(joints))
        if min(fv) < 0 or min(fc) < 0:
            raise DescriptionError(f"{source}:friction: coefficients must be >= 0")
    gravity = _vec(data, "gravity_world", source, default=(0.0, 0.0, -9.81))
    return RobotDescription(
        name=name, base=base_link, joints=joints, links=links, end_effector=ee_obj,
        world_to_base_xyz=_vec(pose, "xyz", f"{source}:base.world_to_base_link", default=(0, 0, 0)),
        world_to_base_rpy=_vec(pose, "rpy", f"{source}:base.world_to_base_link", default=(0, 0, 0)),
        gravity=gravity, friction_viscous=fv, friction_coulomb=fc,
        provenance=str(data.get("provenance", "")).strip(), drive=_parse_drive(data, len(joints), source))


def _parse_drive(data: dict, n: int, source: str) -> DriveDescription | None:
    """The optional ``drive`` block (:mod:`proprio.drive_description`), errors as :class:`DescriptionError`."""
    if data.get("drive") is None:
        return None
    try:
        return drive_from_dict(data["drive"], n, f"{source}:drive")
    except DriveDescriptionError as exc:
        raise DescriptionError(str(exc)) from None


def robot_from_mdh(alpha: list[float], a: list[float], d: list[float], links: list[Link] | None = None,
                   theta_offset: list[float] | None = None, lower: list[float] | None = None,
                   upper: list[float] | None = None, velocity: list[float] | None = None,
                   effort: list[float] | None = None, flange_d: float = 0.0, name: str = "mdh_robot") -> RobotDescription:
    """Build a description from a modified-DH (Craig) table; angles in rad, lengths in m.

    MDH: ``T_{i-1,i} = Rx(α_i) Tx(a_i) Rz(θ_i + offset_i) Tz(d_i)`` — expressed here as a joint origin
    ``xyz = (a_i, −sin α_i d_i, cos α_i d_i)``, ``rpy = (α_i, 0, offset_i)`` and axis z. ``flange_d`` places the
    flange on the last link's z axis. Inertials (``links``) must be given in the MDH link frames; default 1 kg
    point-like placeholders.
    """
    n = len(alpha)
    if not (len(a) == len(d) == n):
        raise DescriptionError(f"MDH table: alpha, a, d lengths differ ({len(alpha)}, {len(a)}, {len(d)})")
    for key, val in (("links", links), ("theta_offset", theta_offset), ("lower", lower), ("upper", upper),
                     ("velocity", velocity), ("effort", effort)):
        if val is not None and len(val) != n:
            raise DescriptionError(f"MDH table: '{key}' has {len(val)} entries, expected {n} (one per joint)")
    off = theta_offset or [0.0] * n
    lo = lower or [-math.pi] * n
    up = upper or [math.pi] * n
    vel = velocity or [1.0] * n
    eff = effort or [100.0] * n
    if links is None:
        links = [Link(f"link_{i + 1}", 1.0, (0.0, 0.0, 0.0), (1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0)) for i in range(n)]
    base = Link("link_0", 0.0, (0.0, 0.0, 0.0), (0.0,) * 6)
    joints = []
    parent = base.name
    for i in range(n):
        ca, sa = math.cos(alpha[i]), math.sin(alpha[i])
        # Rx(α)·Tx(a)·Rz(θ)·Tz(d) == Trans(a, −sα d, cα d)·Rx(α)·Rz(θ); the Tz(d) is moved before the rotation.
        joints.append(Joint(name=f"joint_{i + 1}", parent=parent, child=links[i].name,
                            origin_xyz=(a[i], -sa * d[i], ca * d[i]), origin_rpy=(alpha[i], 0.0, 0.0),
                            axis=(0.0, 0.0, 1.0), lower=lo[i], upper=up[i], velocity=vel[i], effort=eff[i]))
        parent = links[i].name
    if any(abs(o) > 0 for o in off):
        # θ offset: rotate the *child* frame — fold into the origin as an extra yaw after Rx(α)
        joints = [dataclasses.replace(j, origin_rpy=_rpy_of(rpy_to_matrix(j.origin_rpy) @ _rz(o)))
                  for j, o in zip(joints, off)]
    return RobotDescription(name=name, base=base, joints=tuple(joints), links=tuple(links),
                            end_effector=EndEffector(parent=links[-1].name, xyz=(0.0, 0.0, flange_d)),
                            provenance="modified-DH table")


def _rz(t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rpy_of(r: np.ndarray) -> tuple[float, float, float]:
    """Rotation matrix → URDF rpy (roll, pitch, yaw)."""
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if abs(math.cos(pitch)) < 1e-12:
        roll, yaw = math.atan2(-r[1, 2], r[1, 1]), 0.0
    else:
        roll, yaw = math.atan2(r[2, 1], r[2, 2]), math.atan2(r[1, 0], r[0, 0])
    return (roll, pitch, yaw)


def _robot_from_mdh_dict(data: dict, source: str) -> RobotDescription:
    t = data.get("mdh")
    if not isinstance(t, dict):
        raise DescriptionError(f"{source}: proprio-mdh/v1 needs a mapping 'mdh' with alpha_deg, a, d")
    for key in ("a", "d"):
        if key not in t:
            raise DescriptionError(f"{source}:mdh: missing field '{key}'")
    if "alpha" not in t and "alpha_deg" not in t:
        raise DescriptionError(f"{source}:mdh: missing field 'alpha_deg' (or 'alpha' in rad)")
    alpha = [math.radians(x) for x in t["alpha_deg"]] if "alpha_deg" in t else list(t["alpha"])
    off = [math.radians(x) for x in t.get("theta_offset_deg", [])] or None
    n = len(alpha)
    lim = data.get("limits", {})
    def deg_list(key: str) -> list[float] | None:
        return [math.radians(x) for x in lim[key]] if key in lim else None
    links = None
    if "links" in data:
        links = [_parse_link(lk, f"{source}:links[{k}]") for k, lk in enumerate(data["links"])]
    desc = robot_from_mdh(alpha, list(t["a"]), list(t["d"]), links=links, theta_offset=off,
                          lower=[-x for x in deg_list("position_deg")] if "position_deg" in lim else None,
                          upper=deg_list("position_deg"), velocity=deg_list("velocity_deg_s"),
                          effort=lim.get("effort"), flange_d=float(t.get("flange_d", 0.0)),
                          name=str(data.get("name", "mdh_robot")))
    if len(desc.joints) != n:
        raise DescriptionError(f"{source}: MDH table length mismatch")
    return dataclasses.replace(desc, drive=_parse_drive(data, n, source))


def robot_from_urdf(path: str | Path, base_link: str | None = None, tip_link: str | None = None,
                    flange_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> RobotDescription:
    """Import a user's URDF file: the serial chain of revolute joints from ``base_link`` to ``tip_link``.

    Without ``base_link`` the chain starts at the root link; fixed joints right below the root (e.g. a weld to an
    undeclared ``world``) become the base pose. Fixed joints after the last revolute joint place the flange (named
    after the last link), offset further by ``flange_xyz`` [m] in that frame. Fixed joints between movable ones are
    not supported (merge them first); mesh geometry is ignored.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise DescriptionError(f"{path}: not valid XML ({exc})") from exc
    links: dict[str, Link] = {}
    for el in root.findall("link"):
        name = el.get("name")
        inert = el.find("inertial")
        if inert is None:
            links[name] = Link(name, 0.0, (0.0, 0.0, 0.0), (0.0,) * 6)
            continue
        org = inert.find("origin")
        xyz = _floats(org.get("xyz") if org is not None else None, 3)
        rpy = _floats(org.get("rpy") if org is not None else None, 3)
        mass = float(inert.find("mass").get("value"))
        ie = inert.find("inertia")
        vals = tuple(float(ie.get(k, 0.0)) for k in INERTIA_KEYS)
        links[name] = Link(name, mass, xyz, vals, com_rpy=rpy)
    joints_by_child = {}
    for el in root.findall("joint"):
        joints_by_child[el.find("child").get("link")] = el
    by_parent: dict[str, list] = {}
    for el in joints_by_child.values():
        by_parent.setdefault(el.find("parent").get("link"), []).append(el)
    world_to_base = np.eye(4)
    if base_link is None:
        # the root may be an undeclared "world" (Drake's convention); fixed joints below it weld the base to it
        roots = sorted({*links, *by_parent} - set(joints_by_child))
        if len(roots) != 1:
            raise DescriptionError(f"{path}: expected one root link, found {roots}; pass base_link")
        base_name = roots[0]
        while len(by_parent.get(base_name, [])) == 1 and by_parent[base_name][0].get("type") == "fixed":
            world_to_base = world_to_base @ _origin_matrix(by_parent[base_name][0])
            base_name = by_parent[base_name][0].find("child").get("link")
    else:
        base_name = base_link
    if base_name not in links:
        raise DescriptionError(f"{path}: base link {base_name!r} not found")
    # walk down from the base
    chain = []
    cur = base_name
    while cur in by_parent and cur != tip_link:
        kids = by_parent[cur]
        if len(kids) != 1:
            raise DescriptionError(f"{path}: link '{cur}' has {len(kids)} children; only serial chains are supported")
        chain.append(kids[0])
        cur = kids[0].find("child").get("link")
    # fixed joints after the last movable one place the flange (composed, then offset by flange_xyz)
    n_fixed_tail = 0
    while n_fixed_tail < len(chain) and chain[len(chain) - 1 - n_fixed_tail].get("type") == "fixed":
        n_fixed_tail += 1
    flange = np.eye(4)
    for el in chain[len(chain) - n_fixed_tail:]:
        flange = flange @ _origin_matrix(el)
    flange[:3, 3] += flange[:3, :3] @ np.asarray(flange_xyz, dtype=float)
    flange_name = chain[-1].find("child").get("link") if n_fixed_tail else "flange"
    joints = []
    for el in chain[:len(chain) - n_fixed_tail]:
        jtype = el.get("type")
        if jtype not in ("revolute", "continuous"):
            raise DescriptionError(f"{path}: joint '{el.get('name')}' is {jtype}; only revolute joints are supported")
        org = el.find("origin")
        lim = el.find("limit")
        lo = float(lim.get("lower", -math.pi)) if lim is not None else -math.pi
        hi = float(lim.get("upper", math.pi)) if lim is not None else math.pi
        ax = el.find("axis")
        joints.append(Joint(
            name=el.get("name"), parent=el.find("parent").get("link"), child=el.find("child").get("link"),
            origin_xyz=_floats(org.get("xyz") if org is not None else None, 3),
            origin_rpy=_floats(org.get("rpy") if org is not None else None, 3),
            axis=_floats(ax.get("xyz") if ax is not None else "1 0 0", 3), lower=lo, upper=hi,
            velocity=float(lim.get("velocity", 1.0)) if lim is not None else 1.0,
            effort=float(lim.get("effort", 100.0)) if lim is not None else 100.0))
    if not joints:
        raise DescriptionError(f"{path}: no revolute joints found below '{base_name}'")
    data = {
        "name": root.get("name", path.stem),
        "base": {"base_link": _link_to_dict(links[base_name]),
                 "world_to_base_link": {"xyz": world_to_base[:3, 3].tolist(), "rpy": list(_rpy_of(world_to_base))}},
        "joints": [{"name": j.name, "parent": j.parent, "child": j.child, "origin_xyz": list(j.origin_xyz),
                    "origin_rpy": list(j.origin_rpy), "axis": list(j.axis),
                    "limits": {"lower": j.lower, "upper": j.upper, "velocity": j.velocity, "effort": j.effort}}
                   for j in joints],
        "links": [_link_to_dict(links[j.child]) for j in joints],
        "end_effector": {"name": flange_name, "parent": joints[-1].child, "xyz": flange[:3, 3].tolist(),
                         "rpy": list(_rpy_of(flange))},
        "provenance": f"imported from URDF {path.name}",
    }
    drive = drive_from_urdf_element(root, [j.name for j in joints], str(path))   # <transmission>, armature
    if drive is not None:
        data["drive"] = drive.to_dict()
    return robot_from_dict(data, str(path))


def _origin_matrix(joint_el: ET.Element) -> np.ndarray:
    """4×4 transform of a URDF joint's ``<origin>`` (identity when absent)."""
    org = joint_el.find("origin")
    t = np.eye(4)
    t[:3, :3] = rpy_to_matrix(_floats(org.get("rpy") if org is not None else None, 3))
    t[:3, 3] = _floats(org.get("xyz") if org is not None else None, 3)
    return t


def _link_to_dict(link: Link) -> dict[str, Any]:
    return {"name": link.name, "mass": link.mass, "com_xyz": list(link.com_xyz), "com_rpy": list(link.com_rpy),
            "inertia_com": dict(zip(INERTIA_KEYS, link.inertia_com))}


def _floats(text: str | None, size: int) -> tuple[float, ...]:
    if not text:
        return (0.0,) * size
    vals = tuple(float(x) for x in text.split())
    if len(vals) != size:
        raise DescriptionError(f"URDF attribute {text!r}: expected {size} numbers")
    return vals


def builtin_robots() -> list[str]:
    """Names of the robot descriptions shipped in ``proprio/robots``."""
    return sorted(p.name[:-5] for p in resources.files("proprio.robots").iterdir() if p.name.endswith(".yaml"))


def load_robot(name_or_path: str | Path) -> RobotDescription:
    """Load a shipped robot by name (e.g. ``iiwa14_identified``), a YAML file, a URDF file, or a directory with a
    ``robot.yaml`` (e.g. ``../shared/data/kuka_lwr4``)."""
    p = Path(name_or_path)
    if p.is_dir():
        p = p / "robot.yaml"
    if p.suffix.lower() == ".urdf" and p.exists():
        return robot_from_urdf(p)
    if p.exists() and p.suffix.lower() not in (".yaml", ".yml"):
        raise DescriptionError(f"{p}: not a robot description — give a built-in name ({', '.join(builtin_robots())}), "
                               "a .yaml or .urdf file, or a directory with robot.yaml")
    if p.exists():
        text = p.read_text()
        source = str(p)
    else:
        name = str(name_or_path)
        if name not in builtin_robots():
            raise DescriptionError(f"unknown robot {name!r}: not a file and not one of {builtin_robots()}")
        text = resources.files("proprio.robots").joinpath(f"{name}.yaml").read_text()
        source = f"{name}.yaml"
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise DescriptionError(f"{source}: invalid YAML ({exc})") from exc
    return robot_from_dict(data, source)
