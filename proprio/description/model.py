"""The robot description's data model: a serial chain of revolute joints (links, joints, end effector,
collision shapes), its errors, and the rpy ↔ rotation-matrix conventions (URDF fixed-axis roll-pitch-yaw)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from proprio.drive_description import DriveDescription

__all__ = ["CollisionShape", "Joint", "Link", "EndEffector", "RobotDescription", "DescriptionError",
           "DescriptionWarning", "rpy_to_matrix", "matrix_to_rpy", "INERTIA_KEYS"]

INERTIA_KEYS = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")


class DescriptionError(ValueError):
    """A robot description is malformed; the message names the offending field."""


class DescriptionWarning(UserWarning):
    """A robot description was accepted after a repair within numerical tolerance (the message names the link)."""


def rpy_to_matrix(rpy: np.ndarray | list[float]) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw [rad] to a rotation matrix ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_to_rpy(r: np.ndarray) -> tuple[float, float, float]:
    """Rotation matrix → URDF rpy (roll, pitch, yaw)."""
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if abs(math.cos(pitch)) < 1e-12:
        roll, yaw = math.atan2(-r[1, 2], r[1, 1]), 0.0
    else:
        roll, yaw = math.atan2(r[2, 1], r[2, 2]), math.atan2(r[1, 0], r[0, 0])
    return (roll, pitch, yaw)


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
    ``world_to_base_xyz/rpy``. Friction (optional, per joint): viscous [N·m·s/rad] and Coulomb [N·m];
    ``friction_load_dependent``: the joints' Coulomb friction grows with the torque they transmit
    (``F_c = F_c0 + k |τ|``, :func:`proprio.friction_law.load_coulomb`), so identification fits the load gains
    ``k`` (``proprio identify``, as its ``--load-friction``)."""
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
    friction_load_dependent: bool = False
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
        return dataclasses.replace(self, friction_viscous=None, friction_coulomb=None, friction_load_dependent=False)

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
        if self.friction_load_dependent:
            out.setdefault("friction", {})["load_dependent"] = True
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
