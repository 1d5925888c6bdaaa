"""Robots from modified-DH (Craig) tables: :func:`robot_from_mdh` from Python lists, and the ``proprio-mdh/v1``
YAML format."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from proprio.description.fields import (DOC_KEYS, MDH_LIMIT_KEYS, MDH_TABLE_KEYS, MDH_TOP_KEYS, _num, _parse_drive,
                                        _parse_friction, _parse_link, _vec, check_keys)
from proprio.description.model import (DescriptionError, EndEffector, Joint, Link, RobotDescription, matrix_to_rpy,
                                       rpy_to_matrix)

__all__ = ["robot_from_mdh", "robot_from_mdh_dict"]


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


def robot_from_mdh_dict(data: dict, source: str) -> RobotDescription:
    """``proprio-mdh/v1``: the table, limits (symmetric ``position`` or asymmetric ``lower``/``upper``, each also
    ``_deg``), optional inertials and friction. The caller validates the result like any robot YAML
    (:func:`proprio.description.loader.robot_from_dict` of its ``to_dict()``)."""
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
    fv, fc, load_dependent = _parse_friction(data, n, source)
    desc = dataclasses.replace(desc, friction_viscous=fv, friction_coulomb=fc, friction_load_dependent=load_dependent,
                               gravity=_vec(data, "gravity_world", source, default=(0.0, 0.0, -9.81)),
                               provenance=str(data.get("provenance", desc.provenance)).strip(),
                               drive=_parse_drive(data, n, source))
    return desc
