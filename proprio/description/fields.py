"""The robot YAML's fields: the keys each mapping may hold, and the validating readers of vectors, numbers, angles,
links (with the inertia consistency check), collision shapes, joints, friction and the drive block. Every error is a
:class:`~proprio.description.model.DescriptionError` naming the offending field."""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import numpy as np

from proprio import typed_yaml
from proprio.description.model import (INERTIA_KEYS, CollisionShape, DescriptionError, DescriptionWarning, Joint,
                                       Link)
from proprio.drive_description import DriveDescription, DriveDescriptionError, drive_from_dict

__all__ = ["check_keys", "DOC_KEYS"]

# relative tolerance of the physical-consistency checks, × the link's largest principal moment of inertia
INERTIA_RTOL = 1e-4
# the keys each mapping of the robot YAML may hold (anything else is an error naming the nearest valid key) ...
TOP_KEYS = ("format", "name", "provenance", "gravity_world", "base", "joints", "links", "end_effector", "friction",
            "drive")
BASE_KEYS = ("world_to_base_link", "base_link")
POSE_KEYS = ("xyz", "rpy")
LINK_KEYS = ("name", "mass", "com_xyz", "com", "com_rpy", "inertia_com", "inertia", "collision")
SHAPE_KEYS = ("shape", "xyz", "rpy", "radius", "length", "size")
JOINT_KEYS = ("name", "parent", "child", "origin_xyz", "origin_rpy", "axis", "limits")
LIMIT_KEYS = ("lower", "upper", "lower_deg", "upper_deg", "velocity", "velocity_deg", "effort", "acceleration")
EE_KEYS = ("name", "parent", "xyz", "rpy")
FRICTION_KEYS = ("viscous", "coulomb", "load_dependent")
MDH_TOP_KEYS = ("format", "name", "provenance", "gravity_world", "mdh", "limits", "links", "friction", "drive")
MDH_TABLE_KEYS = ("alpha", "alpha_deg", "a", "d", "theta_offset", "theta_offset_deg", "flange_d")
MDH_LIMIT_KEYS = ("position", "position_deg", "lower", "lower_deg", "upper", "upper_deg", "velocity",
                  "velocity_deg_s", "effort", "acceleration")
URDF_REF_KEYS = ("format", "name", "urdf", "base_link", "tip_link", "flange_xyz", "drive")
# ... and the documentation keys every mapping may carry and the loader ignores (robot-numbers/v1 of
# ../shared/data/kuka_lwr4/robot.yaml: units, conventions, notes, alternative parameter sets, source friction)
DOC_KEYS = ("units", "conventions", "note", "notes", "comment", "source", "alternatives",
            "nominal_friction_in_source")


def check_keys(d: dict, allowed: tuple[str, ...] | frozenset[str], where: str,
               ignored: tuple[str, ...] | frozenset[str] = ()) -> None:
    """Refuse a key of mapping ``d`` that is neither ``allowed`` nor in the explicit ``ignored`` list (documentation
    keys a format carries, e.g. ``note``); the error names the key path and the nearest valid key
    (:func:`proprio.typed_yaml.check_keys`, the one strict-key rule of every YAML the app reads)."""
    typed_yaml.check_keys({k: v for k, v in d.items() if k not in ignored}, allowed, where, DescriptionError)


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


def _parse_drive(data: dict, n: int, source: str) -> DriveDescription | None:
    """The optional ``drive`` block (:mod:`proprio.drive_description`), errors as :class:`DescriptionError`."""
    if data.get("drive") is None:
        return None
    try:
        return drive_from_dict(data["drive"], n, f"{source}:drive")
    except DriveDescriptionError as exc:
        raise DescriptionError(str(exc)) from None


def _parse_friction(data: dict, n: int, source: str
                    ) -> tuple[tuple[float, ...] | None, tuple[float, ...] | None, bool]:
    """The optional ``friction: {viscous, coulomb, load_dependent}`` block: n coefficients each, ≥ 0 (both or
    neither: None, None when absent), and ``load_dependent`` (a YAML boolean, default false): the joints' Coulomb
    friction grows with the torque they transmit, ``F_c = F_c0 + k |τ|`` (:func:`proprio.friction_law.load_coulomb`),
    so ``proprio identify`` fits the load gains ``k``. A block may hold ``load_dependent`` alone."""
    fr = data.get("friction")
    if fr is None:
        return None, None, False
    if not isinstance(fr, dict):
        raise DescriptionError(f"{source}:friction: expected a mapping {{viscous, coulomb, load_dependent}}, "
                               f"got {fr!r}")
    check_keys(fr, FRICTION_KEYS, f"{source}:friction", DOC_KEYS)
    load = fr.get("load_dependent", False)
    if not isinstance(load, bool):
        raise DescriptionError(f"{source}:friction.load_dependent: expected true or false, got {load!r}")
    if "load_dependent" in fr and "viscous" not in fr and "coulomb" not in fr:
        return None, None, load
    fv = _vec(fr, "viscous", f"{source}:friction", size=n)
    fc = _vec(fr, "coulomb", f"{source}:friction", size=n)
    if min(fv) < 0 or min(fc) < 0:
        raise DescriptionError(f"{source}:friction: coefficients must be >= 0")
    return fv, fc, load
