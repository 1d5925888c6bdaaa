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
import math
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

__all__ = [
    "CollisionShape", "Joint", "Link", "EndEffector", "RobotDescription", "DescriptionError", "DescriptionWarning",
    "load_robot", "robot_from_dict", "robot_from_mdh", "robot_from_urdf", "builtin_robots", "rpy_to_matrix",
    "check_keys", "nearest_key", "matrix_to_rpy",
]

INERTIA_KEYS = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")


class DescriptionError(ValueError):
    """A robot description is malformed; the message names the offending field."""


class DescriptionWarning(UserWarning):
    """A robot description was accepted after a repair within numerical tolerance (the message names the link)."""


# relative tolerance of the physical-consistency checks, × the link's largest principal moment of inertia
INERTIA_RTOL = 1e-4
# the keys each mapping of the robot YAML may hold (anything else is an error naming the nearest valid key) ...
TOP_KEYS = ("format", "name", "provenance", "gravity_world", "base", "joints", "links", "end_effector", "friction")
BASE_KEYS = ("world_to_base_link", "base_link")
POSE_KEYS = ("xyz", "rpy")
LINK_KEYS = ("name", "mass", "com_xyz", "com", "com_rpy", "inertia_com", "inertia", "collision")
SHAPE_KEYS = ("shape", "xyz", "rpy", "radius", "length", "size")
JOINT_KEYS = ("name", "parent", "child", "origin_xyz", "origin_rpy", "axis", "limits")
LIMIT_KEYS = ("lower", "upper", "lower_deg", "upper_deg", "velocity", "velocity_deg", "effort", "acceleration")
EE_KEYS = ("name", "parent", "xyz", "rpy")
FRICTION_KEYS = ("viscous", "coulomb")
MDH_TOP_KEYS = ("format", "name", "provenance", "gravity_world", "mdh", "limits", "links", "friction")
MDH_TABLE_KEYS = ("alpha", "alpha_deg", "a", "d", "theta_offset", "theta_offset_deg", "flange_d")
MDH_LIMIT_KEYS = ("position", "position_deg", "lower", "lower_deg", "upper", "upper_deg", "velocity",
                  "velocity_deg_s", "effort", "acceleration")
URDF_REF_KEYS = ("format", "name", "urdf", "base_link", "tip_link", "flange_xyz")
# ... and the documentation keys every mapping may carry and the loader ignores (robot-numbers/v1 of
# ../shared/data/kuka_lwr4/robot.yaml: units, conventions, notes, alternative parameter sets, source friction)
DOC_KEYS = ("units", "conventions", "note", "notes", "comment", "source", "alternatives",
            "nominal_friction_in_source")


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
        near = nearest_key(str(key), allowed)
        hint = f"; did you mean '{near}'?" if near else f" (valid: {', '.join(allowed)})"
        raise DescriptionError(f"{where}: unknown key '{key}'{hint}")


def nearest_key(key: str, valid: tuple[str, ...] | frozenset[str]) -> str | None:
    """The valid key closest to a misspelt one: fewest edits (insert, delete, substitute, swap two neighbours), then
    the longest common prefix; None when every valid key needs more edits than a third of its length (at least 2)."""
    def edits(a: str, b: str) -> int:
        d = [[i + j if i * j == 0 else 0 for j in range(len(b) + 1)] for i in range(len(a) + 1)]
        for i in range(1, len(a) + 1):
            for j in range(1, len(b) + 1):
                d[i][j] = min(d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (a[i - 1] != b[j - 1]))
                if i > 1 and j > 1 and a[i - 1] == b[j - 2] and a[i - 2] == b[j - 1]:
                    d[i][j] = min(d[i][j], d[i - 2][j - 2] + 1)
        return d[-1][-1]

    def prefix(a: str, b: str) -> int:
        return next((k for k, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))

    scored = [(edits(key, v), -prefix(key, v), v) for v in valid]
    best = min(scored, default=None)
    return best[2] if best is not None and best[0] <= max(2, len(best[2]) // 3) else None


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
    if not math.isfinite(x):
        raise DescriptionError(f"{where}.{key}: must be a finite number, got {x}")
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
        check_keys(v, INERTIA_KEYS, f"{where}.inertia_com", DOC_KEYS)
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
    check_keys(d, LINK_KEYS, where, DOC_KEYS)
    mass = _num(d, "mass", where, nonneg=True)
    if not math.isfinite(mass):
        raise DescriptionError(f"{where}.mass: must be finite, got {mass}")
    com = _vec(d, "com_xyz" if "com_xyz" in d else "com", where)
    inertia_key = "inertia_com" if "inertia_com" in d else "inertia"
    if inertia_key not in d:
        raise DescriptionError(f"{where}: missing field 'inertia_com'")
    inertia = _parse_inertia(d[inertia_key], where)
    com_rpy = _vec(d, "com_rpy", where, default=(0.0, 0.0, 0.0))
    shapes = tuple(_parse_shape(s, f"{where}.collision[{k}]") for k, s in enumerate(d.get("collision") or []))
    link = Link(name=name, mass=mass, com_xyz=com, inertia_com=inertia, com_rpy=com_rpy, collision=shapes)
    return _check_inertia(link, where)


def _check_inertia(link: Link, where: str) -> Link:
    """Physical consistency of the rotational inertia, with a tolerance scaled by the link's own inertia: principal
    moments must be ≥ 0 and obey the triangle inequality to within ``INERTIA_RTOL`` × the largest moment. Within that
    tolerance the nearest consistent inertia is used (negative moments clipped to 0, a triangle deficit spread over
    the three moments) with a :class:`DescriptionWarning` naming the link; beyond it the link is refused."""
    ixx, iyy, izz, ixy, ixz, iyz = link.inertia_com
    i_c = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])   # in the com_rpy frame
    if not np.all(np.isfinite(i_c)):
        raise DescriptionError(f"{where}.inertia_com: non-finite value")
    eig, vec = np.linalg.eigh(i_c)
    tol = INERTIA_RTOL * float(np.abs(eig).max()) + 1e-15
    if eig[0] < -tol:
        raise DescriptionError(f"{where}.inertia_com: not positive semi-definite (eigenvalues {eig}; tolerance "
                               f"{tol:.2g} kg·m²)")
    a, b, c = eig
    if a + b < c - tol:
        raise DescriptionError(f"{where}.inertia_com: principal moments {eig} violate the triangle inequality "
                               f"(a + b − c = {a + b - c:.3g} kg·m², tolerance {tol:.2g})")
    eps = 1e-9 * float(np.abs(eig).max())             # rounding noise: accepted as is
    if eig[0] >= -eps and a + b >= c - eps:
        return link
    fixed = np.clip(eig, 0.0, None)
    deficit = fixed[2] - fixed[0] - fixed[1]
    if deficit > 0:                                    # nearest point of the plane a + b = c
        fixed = fixed + deficit / 3.0 * np.array([1.0, 1.0, -1.0])
    i_new = vec @ np.diag(fixed) @ vec.T
    warnings.warn(f"{where}.inertia_com: principal moments {eig} are inconsistent within the tolerance {tol:.2g} "
                  f"kg·m² (numerical noise); using the nearest consistent inertia, moments {fixed}",
                  DescriptionWarning, stacklevel=2)
    return dataclasses.replace(link, inertia_com=(float(i_new[0, 0]), float(i_new[1, 1]), float(i_new[2, 2]),
                                                  float(i_new[0, 1]), float(i_new[0, 2]), float(i_new[1, 2])))


def _parse_shape(d: dict, where: str) -> CollisionShape:
    if not isinstance(d, dict) or "shape" not in d:
        raise DescriptionError(f"{where}: expected a mapping with 'shape'")
    check_keys(d, SHAPE_KEYS, where, DOC_KEYS)
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
    check_keys(d, JOINT_KEYS, where, DOC_KEYS)
    axis = np.array(_vec(d, "axis", where))
    norm = np.linalg.norm(axis)
    if not abs(norm - 1.0) < 1e-6:
        raise DescriptionError(f"{where}.axis: must be a unit vector, got {axis.tolist()} (norm {norm:.6g})")
    lim = d.get("limits")
    if not isinstance(lim, dict):
        raise DescriptionError(f"{where}: missing mapping 'limits' (lower, upper, velocity, effort)")
    lw = f"{where}.limits"
    check_keys(lim, LIMIT_KEYS, lw, DOC_KEYS)
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
    if fmt.startswith("proprio-urdf"):
        return _robot_from_urdf_ref(data, source)
    check_keys(data, TOP_KEYS, source, DOC_KEYS)
    name = str(data.get("name", Path(source).stem))
    base = data.get("base") or {}
    pose = (base.get("world_to_base_link") or {}) if isinstance(base, dict) else None
    if not isinstance(base, dict) or not isinstance(pose, dict):
        raise DescriptionError(f"{source}:base: expected a mapping with 'world_to_base_link' {{xyz, rpy}} and "
                               "'base_link'")
    check_keys(base, BASE_KEYS, f"{source}:base", DOC_KEYS)
    check_keys(pose, POSE_KEYS, f"{source}:base.world_to_base_link", DOC_KEYS)
    base_link = _parse_link(base["base_link"], f"{source}:base.base_link") if "base_link" in base else \
        Link("base", 0.0, (0.0, 0.0, 0.0), (0.0,) * 6)
    if not isinstance(data.get("joints"), list) or not isinstance(data.get("links"), list):
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
    check_keys(ee, EE_KEYS, f"{source}:end_effector", DOC_KEYS)
    ee_obj = EndEffector(parent=str(ee.get("parent", links[-1].name)), xyz=_vec(ee, "xyz", f"{source}:end_effector",
                         default=(0, 0, 0)), rpy=_vec(ee, "rpy", f"{source}:end_effector", default=(0, 0, 0)),
                         name=str(ee.get("name", "flange")))
    if ee_obj.parent != links[-1].name:
        raise DescriptionError(f"{source}:end_effector.parent must be the last link '{links[-1].name}'")
    fv, fc = _parse_friction(data, len(joints), source)
    gravity = _vec(data, "gravity_world", source, default=(0.0, 0.0, -9.81))
    return RobotDescription(
        name=name, base=base_link, joints=joints, links=links, end_effector=ee_obj,
        world_to_base_xyz=_vec(pose, "xyz", f"{source}:base.world_to_base_link", default=(0, 0, 0)),
        world_to_base_rpy=_vec(pose, "rpy", f"{source}:base.world_to_base_link", default=(0, 0, 0)),
        gravity=gravity, friction_viscous=fv, friction_coulomb=fc,
        provenance=str(data.get("provenance", "")).strip())


def _parse_friction(data: dict, n: int, source: str) -> tuple[tuple[float, ...] | None, tuple[float, ...] | None]:
    """The optional ``friction: {viscous, coulomb}`` block: n coefficients each, ≥ 0 (None, None when absent)."""
    fr = data.get("friction")
    if fr is None:
        return None, None
    if not isinstance(fr, dict):
        raise DescriptionError(f"{source}:friction: expected a mapping {{viscous, coulomb}}, got {fr!r}")
    check_keys(fr, FRICTION_KEYS, f"{source}:friction", DOC_KEYS)
    fv = _vec(fr, "viscous", f"{source}:friction", size=n)
    fc = _vec(fr, "coulomb", f"{source}:friction", size=n)
    if min(fv) < 0 or min(fc) < 0:
        raise DescriptionError(f"{source}:friction: coefficients must be >= 0")
    return fv, fc


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
        joints = [dataclasses.replace(j, origin_rpy=matrix_to_rpy(rpy_to_matrix(j.origin_rpy) @ _rz(o)))
                  for j, o in zip(joints, off)]
    return RobotDescription(name=name, base=base, joints=tuple(joints), links=tuple(links),
                            end_effector=EndEffector(parent=links[-1].name, xyz=(0.0, 0.0, flange_d)),
                            provenance="modified-DH table")


def _rz(t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def matrix_to_rpy(r: np.ndarray) -> tuple[float, float, float]:
    """Rotation matrix → URDF rpy (roll, pitch, yaw)."""
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if abs(math.cos(pitch)) < 1e-12:
        roll, yaw = math.atan2(-r[1, 2], r[1, 1]), 0.0
    else:
        roll, yaw = math.atan2(r[2, 1], r[2, 2]), math.atan2(r[1, 0], r[0, 0])
    return (roll, pitch, yaw)


def _mdh_list(d: dict, key: str, where: str, n: int | None, deg_key: str | None = "") -> list[float] | None:
    """A list of n numbers under ``key`` (rad, m, …) or ``deg_key`` (degrees, converted); None when neither."""
    deg_key = f"{key}_deg" if deg_key == "" else deg_key
    if key in d and deg_key in d:
        raise DescriptionError(f"{where}: both '{key}' and '{deg_key}' given; keep one")
    use = deg_key if deg_key in d else key
    if use not in d:
        return None
    if n is None:
        if not isinstance(d[use], list) or not d[use]:
            raise DescriptionError(f"{where}.{use}: expected a list of numbers, one per joint, got {d[use]!r}")
        n = len(d[use])
    vals = _vec(d, use, where, size=n)
    return [math.radians(x) for x in vals] if use == deg_key else list(vals)


def _robot_from_mdh_dict(data: dict, source: str) -> RobotDescription:
    """``proprio-mdh/v1``: the table, limits (symmetric ``position`` or asymmetric ``lower``/``upper``, each also
    ``_deg``), optional inertials and friction; the result is validated like any robot YAML."""
    check_keys(data, MDH_TOP_KEYS, source, DOC_KEYS)
    t = data.get("mdh")
    if not isinstance(t, dict):
        raise DescriptionError(f"{source}: proprio-mdh/v1 needs a mapping 'mdh' with alpha_deg, a, d")
    tw = f"{source}:mdh"
    check_keys(t, MDH_TABLE_KEYS, tw, DOC_KEYS)
    for key in ("a", "d"):
        if key not in t:
            raise DescriptionError(f"{tw}: missing field '{key}'")
    alpha = _mdh_list(t, "alpha", tw, None)
    if alpha is None:
        raise DescriptionError(f"{tw}: missing field 'alpha_deg' (or 'alpha' in rad)")
    n = len(alpha)
    a, d = _mdh_list(t, "a", tw, n, None), _mdh_list(t, "d", tw, n, None)
    lim = data.get("limits") or {}
    lw = f"{source}:limits"
    if not isinstance(lim, dict):
        raise DescriptionError(f"{lw}: expected a mapping, got {lim!r}")
    check_keys(lim, MDH_LIMIT_KEYS, lw, DOC_KEYS)
    pos = _mdh_list(lim, "position", lw, n)
    lower, upper = _mdh_list(lim, "lower", lw, n), _mdh_list(lim, "upper", lw, n)
    if pos is not None and (lower is not None or upper is not None):
        raise DescriptionError(f"{lw}: give either symmetric 'position(_deg)' or 'lower(_deg)'/'upper(_deg)'")
    if (lower is None) != (upper is None):
        raise DescriptionError(f"{lw}: 'lower' and 'upper' go together")
    if pos is not None:
        lower, upper = [-x for x in pos], pos
    links = None
    if "links" in data:
        if not isinstance(data["links"], list):
            raise DescriptionError(f"{source}:links: expected a list, one per joint")
        links = [_parse_link(lk, f"{source}:links[{k}]") for k, lk in enumerate(data["links"])]
    desc = robot_from_mdh(alpha, a, d, links=links, theta_offset=_mdh_list(t, "theta_offset", tw, n),
                          lower=lower, upper=upper, velocity=_mdh_list(lim, "velocity", lw, n, "velocity_deg_s"),
                          effort=_mdh_list(lim, "effort", lw, n, None), flange_d=_num(t, "flange_d", tw, 0.0),
                          name=str(data.get("name", "mdh_robot")))
    acc = _mdh_list(lim, "acceleration", lw, n, None)
    if acc is not None:
        desc = dataclasses.replace(desc, joints=tuple(dataclasses.replace(j, acceleration=x)
                                                      for j, x in zip(desc.joints, acc)))
    fv, fc = _parse_friction(data, n, source)
    desc = dataclasses.replace(desc, friction_viscous=fv, friction_coulomb=fc,
                               gravity=_vec(data, "gravity_world", source, default=(0.0, 0.0, -9.81)),
                               provenance=str(data.get("provenance", desc.provenance)).strip())
    return robot_from_dict(desc.to_dict(), source)          # the same checks as every robot YAML


def _robot_from_urdf_ref(data: dict, source: str) -> RobotDescription:
    """``proprio-urdf/v1``: a URDF file (relative to this YAML) with the chain's ``base_link``/``tip_link`` for
    URDFs where it is ambiguous, and an optional ``flange_xyz`` [m] tool offset."""
    check_keys(data, URDF_REF_KEYS, source, DOC_KEYS)
    if "urdf" not in data:
        raise DescriptionError(f"{source}: proprio-urdf/v1 needs 'urdf' (a file, relative to this YAML)")
    path = Path(source).parent / str(data["urdf"])
    if not path.exists():
        raise DescriptionError(f"{source}:urdf: {path} not found")
    opt = {k: str(data[k]) for k in ("base_link", "tip_link") if k in data}
    desc = robot_from_urdf(path, flange_xyz=_vec(data, "flange_xyz", source, default=(0.0, 0.0, 0.0)), **opt)
    return dataclasses.replace(desc, name=str(data.get("name", desc.name)))


def robot_from_urdf(path: str | Path, base_link: str | None = None, tip_link: str | None = None,
                    flange_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> RobotDescription:
    """Import a URDF file; see :func:`proprio.urdf.robot_from_urdf` (the URDF reader lives beside the writer)."""
    from proprio.urdf import robot_from_urdf as read

    return read(path, base_link, tip_link, flange_xyz)


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
