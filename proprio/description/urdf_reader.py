"""Reading a user's URDF (:func:`proprio.description.robot_from_urdf` validates what :func:`urdf_robot_data` reads;
the writer is :mod:`proprio.urdf`)."""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from proprio.description.model import INERTIA_KEYS, DescriptionError, Link, matrix_to_rpy, rpy_to_matrix
from proprio.drive_description import drive_from_urdf_element

__all__ = ["urdf_robot_data"]

_ACTUATED = ("revolute", "continuous")
_END_FRAME_NAMES = ("tool0", "flange", "ee_link", "tcp", "tool")   # preferred end frames when several hang off the tip


@dataclass(frozen=True)
class _UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    x: np.ndarray                 # 4×4 pose of the joint frame in the parent link frame
    axis: tuple[float, float, float]
    lower: float
    upper: float
    velocity: float
    effort: float


def _floats(text: str | None, size: int, where: str) -> tuple[float, ...]:
    if not text:
        return (0.0,) * size
    try:
        vals = tuple(float(x) for x in text.split())
    except ValueError as exc:
        raise DescriptionError(f"{where}: {text!r} is not {size} numbers") from exc
    if len(vals) != size or not all(math.isfinite(v) for v in vals):
        raise DescriptionError(f"{where}: expected {size} finite numbers, got {text!r}")
    return vals


def _pose(xyz: tuple[float, ...], rpy: tuple[float, ...]) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rpy_to_matrix(rpy)
    t[:3, 3] = xyz
    return t


def _read_urdf(path: Path) -> tuple[str, dict[str, Link], list[_UrdfJoint]]:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise DescriptionError(f"{path}: not valid XML ({exc})") from exc
    except OSError as exc:
        raise DescriptionError(f"{path}: cannot read ({exc.strerror})") from exc
    links: dict[str, Link] = {}
    for el in root.findall("link"):
        name = el.get("name")
        inert = el.find("inertial")
        if inert is None:
            links[name] = Link(name, 0.0, (0.0, 0.0, 0.0), (0.0,) * 6)
            continue
        where = f"{path}: link '{name}' inertial"
        org, mass_el, ie = inert.find("origin"), inert.find("mass"), inert.find("inertia")
        xyz = _floats(org.get("xyz") if org is not None else None, 3, f"{where} origin xyz")
        rpy = _floats(org.get("rpy") if org is not None else None, 3, f"{where} origin rpy")
        mass = _floats(mass_el.get("value") if mass_el is not None else None, 1, f"{where} mass")[0]
        vals = tuple(_floats(ie.get(k, "0") if ie is not None else "0", 1, f"{where} inertia {k}")[0]
                     for k in INERTIA_KEYS)
        links[name] = Link(name, mass, xyz, vals, com_rpy=rpy)
    joints = []
    for el in root.findall("joint"):
        name, jtype = el.get("name"), el.get("type")
        where = f"{path}: joint '{name}'"
        par, chi = el.find("parent"), el.find("child")
        if par is None or chi is None:
            raise DescriptionError(f"{where}: needs <parent link=…/> and <child link=…/>")
        org, lim, ax = el.find("origin"), el.find("limit"), el.find("axis")
        x = _pose(_floats(org.get("xyz") if org is not None else None, 3, f"{where} origin xyz"),
                  _floats(org.get("rpy") if org is not None else None, 3, f"{where} origin rpy"))

        def limit(key: str, default: float) -> float:
            return _floats(lim.get(key), 1, f"{where} limit {key}")[0] if lim is not None and lim.get(key) else default
        joints.append(_UrdfJoint(name, jtype, par.get("link"), chi.get("link"), x,
                                 _floats(ax.get("xyz") if ax is not None else "1 0 0", 3, f"{where} axis"),
                                 limit("lower", -math.pi), limit("upper", math.pi), limit("velocity", 1.0),
                                 limit("effort", 100.0)))
    return root.get("name", path.stem), links, joints


def _lump(name: str, parts: list[tuple[Link, np.ndarray]]) -> Link:
    """One rigid body from links welded together: ``parts`` = (link, 4×4 pose of its frame in the body frame).
    Masses add, the CoM is the mass-weighted mean, inertias move to it by the parallel-axis theorem; the result is
    expressed in the body frame (``com_rpy`` = 0). The body's own link is returned as is when nothing else weighs."""
    own = parts[0][0]
    if all(lk.mass == 0.0 and not any(lk.inertia_com) for lk, _ in parts[1:]):
        return own
    masses = np.array([lk.mass for lk, _ in parts])
    coms = np.array([x[:3, :3] @ np.asarray(lk.com_xyz) + x[:3, 3] for lk, x in parts])
    m = float(masses.sum())
    c = masses @ coms / m if m > 0 else np.zeros(3)
    inertia = np.zeros((3, 3))
    for (lk, x), mi, ci in zip(parts, masses, coms):
        d = ci - c
        inertia += x[:3, :3] @ lk.inertia_matrix_link() @ x[:3, :3].T + mi * (d @ d * np.eye(3) - np.outer(d, d))
    vals = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2])
    return Link(name, m, tuple(float(v) for v in c), tuple(float(v) for v in vals))


def urdf_robot_data(path: str | Path, base_link: str | None = None, tip_link: str | None = None,
                    flange_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict:
    """The robot mapping (the ``proprio-robot/v1`` fields) of a URDF file, before validation: how the chain, base,
    lumped links and flange are found is :func:`proprio.description.robot_from_urdf`'s docstring."""
    path = Path(path)
    name, links, joints = _read_urdf(path)
    by_child: dict[str, _UrdfJoint] = {}
    for j in joints:
        if j.child in by_child:
            raise DescriptionError(f"{path}: link '{j.child}' is the child of two joints ('{by_child[j.child].name}', "
                                   f"'{j.name}'); a URDF is a tree")
        by_child[j.child] = j
        links.setdefault(j.parent, Link(j.parent, 0.0, (0.0, 0.0, 0.0), (0.0,) * 6))  # an undeclared 'world'
        if j.child not in links:
            raise DescriptionError(f"{path}: joint '{j.name}' names child link '{j.child}', which is not declared")
    kids: dict[str, list[_UrdfJoint]] = {}
    for j in joints:
        kids.setdefault(j.parent, []).append(j)

    def ancestry(link: str) -> list[_UrdfJoint]:
        out: list[_UrdfJoint] = []
        while link in by_child:
            out.append(by_child[link])
            link = out[-1].parent
        return out[::-1]

    for lk in (base_link, tip_link):
        if lk is not None and lk not in links:
            raise DescriptionError(f"{path}: link {lk!r} not found (links: {sorted(links)})")
    actuated = [j for j in joints if j.type != "fixed"]      # the chain is found from every moving joint
    if not actuated:
        raise DescriptionError(f"{path}: no revolute joints (an arm needs revolute or continuous joints)")
    if tip_link is None:
        tips = [j for j in actuated if set(a.name for a in actuated) <= {a.name for a in ancestry(j.child)}]
        if not tips:
            leaves = [lk for lk in links if lk not in kids and any(j.type != "fixed" for j in ancestry(lk))]
            paths = [ancestry(lk) for lk in leaves]
            common = next((k for k in range(min(map(len, paths))) if len({id(pa[k]) for pa in paths}) > 1),
                          min(map(len, paths)))
            at = f" at link '{paths[0][common - 1].child}'" if common > 0 else ""
            raise DescriptionError(
                f"{path}: the actuated joints branch{at} ({', '.join(j.name for j in actuated)}), so the serial "
                f"chain is ambiguous: pass tip_link (and base_link), one of the candidate tips {', '.join(leaves)} "
                "or a link on the way to one — on the command line --tip LINK (--base LINK), or in a robot YAML "
                "{format: proprio-urdf/v1, urdf: FILE, tip_link: LINK}")
        on_path = ancestry(tips[0].child)
    else:
        on_path = ancestry(tip_link)
    if base_link is not None:
        names = [j.parent for j in on_path] + [j.child for j in on_path]
        if base_link not in names:
            raise DescriptionError(f"{path}: base_link '{base_link}' is not on the chain to the tip")
        cut = next((k for k, j in enumerate(on_path) if j.parent == base_link), len(on_path))
        above, on_path = on_path[:cut], on_path[cut:]
    else:
        first = next((k for k, j in enumerate(on_path) if j.type != "fixed"), len(on_path))
        above, on_path = on_path[:first], on_path[first:]
    bad = [j for j in above + on_path if j.type not in _ACTUATED + ("fixed",)]
    if bad:
        raise DescriptionError(f"{path}: joint '{bad[0].name}' is {bad[0].type}; only revolute (and continuous) "
                               "joints are supported")
    if any(j.type != "fixed" for j in above):
        moving = next(j for j in above if j.type != "fixed")
        raise DescriptionError(f"{path}: joint '{moving.name}' above base_link '{base_link}' is not fixed")
    chain = [j for j in on_path if j.type in _ACTUATED]
    if not chain:
        raise DescriptionError(f"{path}: no revolute joints found in the chain")
    world_to_base = np.eye(4)
    for j in above:
        world_to_base = world_to_base @ j.x
    base_name = chain[0].parent if base_link is None else base_link

    def welded(body: str) -> list[tuple[str, np.ndarray]]:
        """``body`` and the links below it attached through fixed joints only, with their poses in its frame."""
        out, todo = [(body, np.eye(4))], [(body, np.eye(4))]
        while todo:
            lk, x = todo.pop()
            for j in kids.get(lk, []):
                if j.type == "fixed":
                    out.append((j.child, x @ j.x))
                    todo.append(out[-1])
        return out

    bodies = [base_name] + [j.child for j in chain]
    groups = [welded(b) for b in bodies]
    data_joints = []
    for k, j in enumerate(chain):
        pose_in_prev = dict(groups[k])
        if j.parent not in pose_in_prev:
            raise DescriptionError(f"{path}: joint '{j.name}' is not welded to the body of the previous joint")
        x = pose_in_prev[j.parent] @ j.x
        data_joints.append({"name": j.name, "parent": bodies[k], "child": j.child, "origin_xyz": x[:3, 3].tolist(),
                            "origin_rpy": list(matrix_to_rpy(x[:3, :3])), "axis": list(j.axis),
                            "limits": {"lower": j.lower, "upper": j.upper, "velocity": j.velocity,
                                       "effort": j.effort}})
    lumped = [_lump(b, [(links[lk], x) for lk, x in g]) for b, g in zip(bodies, groups)]
    last = dict(groups[-1])
    if tip_link is not None and tip_link in last:
        ee_name = tip_link
    else:
        leaves = [lk for lk in last if lk != bodies[-1] and not any(j.type == "fixed" for j in kids.get(lk, []))]
        preferred = [nm for nm in _END_FRAME_NAMES if nm in leaves] + [lk for lk in leaves if lk in _END_FRAME_NAMES]
        if len(leaves) > 1 and not preferred:
            raise DescriptionError(f"{path}: several end frames hang off '{bodies[-1]}' ({', '.join(leaves)}): pass "
                                   "tip_link")
        ee_name = preferred[0] if preferred else (leaves[0] if leaves else "flange")
    flange = last.get(ee_name, np.eye(4)).copy()
    flange[:3, 3] += flange[:3, :3] @ np.asarray(flange_xyz, dtype=float)
    data = {
        "name": name,
        "base": {"base_link": _link_dict(lumped[0]),
                 "world_to_base_link": {"xyz": world_to_base[:3, 3].tolist(),
                                        "rpy": list(matrix_to_rpy(world_to_base[:3, :3]))}},
        "joints": data_joints,
        "links": [_link_dict(lk) for lk in lumped[1:]],
        "end_effector": {"name": ee_name, "parent": bodies[-1], "xyz": flange[:3, 3].tolist(),
                         "rpy": list(matrix_to_rpy(flange[:3, :3]))},
        "provenance": f"imported from URDF {path.name}",
    }
    drive = drive_from_urdf_element(ET.parse(path).getroot(), [j.name for j in chain], str(path))
    if drive is not None:                              # <transmission> reductions, <dynamics armature>
        data["drive"] = drive.to_dict()
    return data


def _link_dict(link: Link) -> dict:
    return {"name": link.name, "mass": link.mass, "com_xyz": list(link.com_xyz), "com_rpy": list(link.com_rpy),
            "inertia_com": dict(zip(INERTIA_KEYS, link.inertia_com))}
