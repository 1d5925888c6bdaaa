"""URDF both ways: emit an in-memory URDF string from a :class:`RobotDescription` (for Drake's parser and pinocchio),
and (in :mod:`proprio.description.urdf_reader`) import a user's URDF: :func:`proprio.description.robot_from_urdf`.

With ``visual=True`` every link also gets simple visual geometry (Drake's illustration role, e.g. for Meshcat): its
collision primitives where it has any, else a stick figure drawn from the kinematics — a cylinder from the link origin
to the next joint (or the flange) and a hub along the joint axis.
"""
from __future__ import annotations

import math
from xml.sax.saxutils import quoteattr

from proprio.description import CollisionShape, Link, RobotDescription
from proprio.payload import Payload

__all__ = ["to_urdf", "visual_shapes", "LINK_RGBA", "BASE_RGBA"]

LINK_RGBA = (0.93, 0.45, 0.10, 1.0)    # moving links (KUKA orange)
BASE_RGBA = (0.35, 0.35, 0.35, 1.0)    # the fixed base link
STICK_RADIUS = 0.035                   # [m] generated link segments
HUB_RADIUS, HUB_LENGTH = 0.05, 0.10    # [m] generated joint hubs along the axis


def _f(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def _inertial(link: Link) -> str:
    ixx, iyy, izz, ixy, ixz, iyz = link.inertia_com
    mass = link.mass
    if mass <= 0.0:  # massless links are not allowed by some parsers; use a negligible inertial
        mass, ixx, iyy, izz, ixy, ixz, iyz = 1e-9, 1e-12, 1e-12, 1e-12, 0.0, 0.0, 0.0
    return (f'<inertial><origin xyz="{_f(link.com_xyz)}" rpy="{_f(link.com_rpy)}"/><mass value="{mass!r}"/>'
            f'<inertia ixx="{ixx!r}" iyy="{iyy!r}" izz="{izz!r}" ixy="{ixy!r}" ixz="{ixz!r}" iyz="{iyz!r}"/>'
            '</inertial>')


def _geometry(s: CollisionShape) -> str:
    if s.shape == "sphere":
        return f'<sphere radius="{s.radius!r}"/>'
    if s.shape == "cylinder":
        return f'<cylinder radius="{s.radius!r}" length="{s.length!r}"/>'
    return f'<box size="{_f(s.size)}"/>'


def _z_to(u) -> tuple[float, float, float]:
    """URDF rpy of a frame whose z axis points along ``u`` (Rz(yaw)·Ry(pitch) maps z onto u)."""
    x, y, z = (float(c) for c in u)
    return (0.0, math.atan2(math.hypot(x, y), z), math.atan2(y, x))


def _segment(tip, radius: float) -> CollisionShape | None:
    """A cylinder from the link origin to ``tip`` [m] (None when the two nearly coincide)."""
    length = math.sqrt(sum(float(c) ** 2 for c in tip))
    if length < 1e-3:
        return None
    return CollisionShape("cylinder", tuple(0.5 * float(c) for c in tip), _z_to(tip), radius=radius, length=length)


def visual_shapes(desc: RobotDescription) -> dict[str, tuple[CollisionShape, ...]]:
    """Visual primitives per link name (base included): a link's collision primitives where it has any, else a
    stick figure from the kinematics — a cylinder to the next joint origin (to the flange for the last link) and a
    hub cylinder along the link's joint axis at its origin."""
    tips = [j.origin_xyz for j in desc.joints[1:]] + [desc.end_effector.xyz]
    out = {desc.base.name: desc.base.collision or tuple(
        s for s in [_segment(desc.joints[0].origin_xyz, 1.5 * STICK_RADIUS)] if s is not None)}
    for joint, link, tip in zip(desc.joints, desc.links, tips):
        hub = CollisionShape("cylinder", (0.0, 0.0, 0.0), _z_to(joint.axis), radius=HUB_RADIUS, length=HUB_LENGTH)
        out[link.name] = link.collision or tuple(s for s in [hub, _segment(tip, STICK_RADIUS)] if s is not None)
    return out


def _link(link: Link, collision: bool, visual: tuple[CollisionShape, ...] = (),
          rgba: tuple[float, ...] = LINK_RGBA) -> str:
    body = _inertial(link)
    if collision:
        for k, s in enumerate(link.collision):
            body += (f'<collision name="{link.name}_c{k}"><origin xyz="{_f(s.xyz)}" rpy="{_f(s.rpy)}"/>'
                     f'<geometry>{_geometry(s)}</geometry></collision>')
    for k, s in enumerate(visual):
        body += (f'<visual name="{link.name}_v{k}"><origin xyz="{_f(s.xyz)}" rpy="{_f(s.rpy)}"/>'
                 f'<geometry>{_geometry(s)}</geometry><material name="{link.name}_m{k}"><color rgba="{_f(rgba)}"/>'
                 '</material></visual>')
    return f'<link name={quoteattr(link.name)}>{body}</link>'


def to_urdf(desc: RobotDescription, payload: Payload | None = None, collision: bool = True,
            world_joint: bool = True, visual: bool = False) -> str:
    """URDF text for ``desc``: base welded to ``world`` (if ``world_joint``), revolute joints with limits and one
    actuator each (named as the joint, effort limit = joint effort), a fixed
    ``flange`` frame link, and optionally a ``payload`` body welded to the flange. ``visual`` adds
    :func:`visual_shapes` as ``<visual>`` elements (links ``LINK_RGBA``, base ``BASE_RGBA``)."""
    shapes = visual_shapes(desc) if visual else {}
    parts = [f'<?xml version="1.0"?><robot name={quoteattr(desc.name)}>']
    if world_joint:
        parts.append('<link name="world"/>')
        parts.append(f'<joint name="world_to_base" type="fixed"><parent link="world"/>'
                     f'<child link={quoteattr(desc.base.name)}/><origin xyz="{_f(desc.world_to_base_xyz)}" '
                     f'rpy="{_f(desc.world_to_base_rpy)}"/></joint>')
    parts.append(_link(desc.base, collision, shapes.get(desc.base.name, ()), BASE_RGBA))
    for j, lk in zip(desc.joints, desc.links):
        parts.append(_link(lk, collision, shapes.get(lk.name, ())))
        parts.append(
            f'<joint name={quoteattr(j.name)} type="revolute"><parent link={quoteattr(j.parent)}/>'
            f'<child link={quoteattr(j.child)}/><origin xyz="{_f(j.origin_xyz)}" rpy="{_f(j.origin_rpy)}"/>'
            f'<axis xyz="{_f(j.axis)}"/><limit lower="{j.lower!r}" upper="{j.upper!r}" '
            f'effort="{j.effort!r}" velocity="{j.velocity!r}"/></joint>')
        # one actuator per joint (same name), so the plant has an actuation input port and Drake's
        # InverseDynamicsController accepts it; unconnected, the actuation is zero
        parts.append(f'<transmission name={quoteattr(j.name + "_transmission")} type="SimpleTransmission">'
                     f'<actuator name={quoteattr(j.name)}/><joint name={quoteattr(j.name)}/>'
                     '<mechanicalReduction>1</mechanicalReduction></transmission>')
    ee = desc.end_effector
    parts.append(f'<link name={quoteattr(ee.name)}/>')
    parts.append(f'<joint name="{ee.name}_joint" type="fixed"><parent link={quoteattr(ee.parent)}/>'
                 f'<child link={quoteattr(ee.name)}/><origin xyz="{_f(ee.xyz)}" rpy="{_f(ee.rpy)}"/></joint>')
    if payload is not None and payload.mass > 0:
        ixx, iyy, izz, ixy, ixz, iyz = payload.inertia
        # a point-mass payload needs a tiny inertia to be a valid body
        eps = 1e-9 if max(ixx, iyy, izz) == 0.0 else 0.0
        pl = Link("payload", payload.mass, payload.com_flange, (ixx + eps, iyy + eps, izz + eps, ixy, ixz, iyz))
        parts.append(_link(pl, collision=False))
        parts.append(f'<joint name="payload_joint" type="fixed"><parent link={quoteattr(ee.name)}/>'
                     '<child link="payload"/><origin xyz="0 0 0" rpy="0 0 0"/></joint>')
    parts.append("</robot>")
    return "".join(parts)
