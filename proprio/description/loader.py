"""Loading a robot: by shipped name, YAML file (``proprio-robot/v1``, ``robot-numbers/v1``, ``proprio-mdh/v1``,
``proprio-urdf/v1``), URDF file or data directory; :func:`robot_from_dict` validates a parsed mapping."""
from __future__ import annotations

import dataclasses
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from proprio.description.fields import (BASE_KEYS, DOC_KEYS, EE_KEYS, POSE_KEYS, TOP_KEYS, URDF_REF_KEYS,
                                        _parse_drive, _parse_friction, _parse_joint, _parse_link, _vec, check_keys)
from proprio.description.mdh import robot_from_mdh_dict
from proprio.description.model import DescriptionError, EndEffector, Link, RobotDescription
from proprio.description.urdf_reader import urdf_robot_data

__all__ = ["robot_from_dict", "robot_from_urdf", "builtin_robots", "load_robot"]


def robot_from_dict(data: dict[str, Any], source: str = "<dict>") -> RobotDescription:
    """Validate a parsed YAML mapping (``proprio-robot/v1``, ``robot-numbers/v1`` or ``proprio-mdh/v1``)."""
    if not isinstance(data, dict):
        raise DescriptionError(f"{source}: top level must be a mapping")
    fmt = str(data.get("format", "proprio-robot/v1"))
    if fmt.startswith("proprio-mdh"):
        return robot_from_dict(robot_from_mdh_dict(data, source).to_dict(), source)   # checked like any YAML
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
    fv, fc, load_dependent = _parse_friction(data, len(joints), source)
    gravity = _vec(data, "gravity_world", source, default=(0.0, 0.0, -9.81))
    return RobotDescription(
        name=name, base=base_link, joints=joints, links=links, end_effector=ee_obj,
        world_to_base_xyz=_vec(pose, "xyz", f"{source}:base.world_to_base_link", default=(0, 0, 0)),
        world_to_base_rpy=_vec(pose, "rpy", f"{source}:base.world_to_base_link", default=(0, 0, 0)),
        gravity=gravity, friction_viscous=fv, friction_coulomb=fc, friction_load_dependent=load_dependent,
        provenance=str(data.get("provenance", "")).strip(), drive=_parse_drive(data, len(joints), source))


def _robot_from_urdf_ref(data: dict, source: str) -> RobotDescription:
    """``proprio-urdf/v1``: a URDF file (relative to this YAML) with the chain's ``base_link``/``tip_link`` for
    URDFs where it is ambiguous, an optional ``flange_xyz`` [m] tool offset, and an optional ``drive`` block
    (:mod:`proprio.drive_description`, as in ``proprio-robot/v1``) for what the URDF cannot say: ``tau_kind``
    (required there: a URDF never says what τ is), the coupling, torque constants, motor friction, offsets. Its keys
    win over the URDF's own transmissions and armature (``gear_ratio``, ``rotor_inertia``), which fill in the keys it
    leaves out, so a current-sensed arm with ``<transmission>`` reductions needs only ``drive: {tau_kind: drive}``."""
    check_keys(data, URDF_REF_KEYS, source, DOC_KEYS)
    if "urdf" not in data:
        raise DescriptionError(f"{source}: proprio-urdf/v1 needs 'urdf' (a file, relative to this YAML)")
    path = Path(source).parent / str(data["urdf"])
    if not path.exists():
        raise DescriptionError(f"{source}:urdf: {path} not found")
    opt = {k: str(data[k]) for k in ("base_link", "tip_link") if k in data}
    desc = robot_from_urdf(path, flange_xyz=_vec(data, "flange_xyz", source, default=(0.0, 0.0, 0.0)), **opt)
    desc = dataclasses.replace(desc, name=str(data.get("name", desc.name)))
    if data.get("drive") is None:
        return desc
    drive = data["drive"]
    if not isinstance(drive, dict):
        raise DescriptionError(f"{source}:drive: expected a mapping (tau_kind, gear_ratio, coupling, ...)")
    if "tau_kind" not in drive:
        raise DescriptionError(f"{source}:drive.tau_kind: required (link_sensor: a joint-torque sensor behind the "
                               "gear; drive: a drive torque from motor currents) — a URDF does not say what τ is")
    from_urdf = {k: list(getattr(desc.drive, k)) for k in ("gear_ratio", "rotor_inertia")} if desc.drive else {}
    return dataclasses.replace(desc, drive=_parse_drive({"drive": {**from_urdf, **drive}}, desc.n, source))


def robot_from_urdf(path: str | Path, base_link: str | None = None, tip_link: str | None = None,
                    flange_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> RobotDescription:
    """Import a URDF as the ROS ecosystem writes it: the serial chain is found from the actuated (revolute or
    continuous) joints, whatever fixed frames surround it (``world`` and its weld, ``base``, ``base_link_inertia``,
    ``flange``, ``tool0``, sensor frames between two joints).

    * The chain runs from the root to the deepest actuated joint when every actuated joint lies on that path; when
      they branch (e.g. a gripper's fingers, two arms) the chain is ambiguous and ``tip_link`` picks it.
    * The base is the parent link of the first actuated joint (or ``base_link``); the fixed joints from the root
      to it make the base pose in the world.
    * Links welded by fixed joints to a moving body (including frames between two actuated joints) are lumped onto
      that body: masses, CoM and inertia combined (parallel-axis theorem) in the body's frame.
    * The flange is ``tip_link`` when it is welded to the last body; else the one end frame welded to it (when there
      are several: ``tool0``, ``flange``, ``ee_link``, ``tcp``, ``tool`` in that order), else the last body's frame;
      ``flange_xyz`` [m] adds a tool offset in that frame.

    A ``<transmission>`` reduction ≠ 1 or a ``<dynamics armature>`` becomes the description's ``drive`` block
    (:func:`proprio.drive_description.drive_from_urdf_element`). Meshes, ``<dynamics>`` damping/friction and moving
    side branches off the chain are not imported."""
    return robot_from_dict(urdf_robot_data(path, base_link, tip_link, flange_xyz), str(path))


def builtin_robots() -> list[str]:
    """Names of the robot descriptions shipped in ``proprio/robots``."""
    return sorted(p.name[:-5] for p in resources.files("proprio.robots").iterdir() if p.name.endswith(".yaml"))


def load_robot(name_or_path: str | Path, base_link: str | None = None, tip_link: str | None = None
               ) -> RobotDescription:
    """Load a shipped robot by name (e.g. ``iiwa14_identified``), a YAML file, a URDF file, or a directory with a
    ``robot.yaml`` (e.g. ``../shared/data/kuka_lwr4``). ``base_link``/``tip_link`` select a URDF file's chain where
    it is ambiguous (the CLI's ``--base``/``--tip``); for anything else they are an error (a ``proprio-urdf/v1``
    YAML names them itself)."""
    p = Path(name_or_path)
    if p.is_dir():
        p = p / "robot.yaml"
    if p.suffix.lower() == ".urdf" and p.exists():
        return robot_from_urdf(p, base_link, tip_link)
    if base_link is not None or tip_link is not None:
        raise DescriptionError(f"{name_or_path}: base/tip links select the chain of a URDF file only (this is not a "
                               ".urdf file); a robot YAML of format proprio-urdf/v1 names them as base_link/tip_link")
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
