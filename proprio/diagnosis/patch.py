"""The diagnosis as a twin patch: the physical effects a diagnosis found, with their fitted parameters, in the twin
config format (``twin_patch.yaml``), so that ``proprio simulate --twin BASE --patch twin_patch.yaml`` runs the base
twin with them added (:func:`proprio.diagrams.twin.merge_twin_patch`).

Each selected *physical* step contributes its candidate's :meth:`~proprio.diagnosis.candidates.base.Candidate.patch` of
the final joint fit (the last step's ``params``): library effects as ``effects:`` blocks (``sensor_offset`` and
``sensor_gain`` merge into one ``sensor_offset_gain`` block), an unmodelled payload as ``payload:``, a rigid-body
parameter error as a corrected robot description (physically consistent inertials, written as a robot YAML next
to the patch and named by its ``robot:`` key), a drive term (rotor inertia, motor friction, drive offsets) as the
same description with its drive block corrected. Every step's description changes the same base robot: they merge
leaf by leaf into ONE corrected description (:func:`merge_entries`); only two steps setting the same value
differently is a conflict, kept out of the patch and said in its comments — never an error. An unmodelled white
noise adds a ``torque_noise`` block — only on joints whose residual passes both whiteness tests, at the level the raw τ itself carries at the robot's rate
(:func:`proprio.diagnosis.selection.forward.attribute`'s noise finding): a structured residual is never patched as noise. Data-path
(processing) steps never go into a patch; the comments at the top say what was left out and why, and give each
entry's held-out gain and fitted parameters with their 95 % CI.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from proprio.diagnosis.data import SimModel
from proprio.diagnosis.attribution import Attribution
from proprio.io import atomic_write_text

__all__ = ["PatchEntry", "Patch", "MergedPatch", "patch_entries", "merge_entries", "undetermined_load_gains",
           "twin_patch", "write_twin_patch", "make_patch", "MAX_COMMENT_PARAMS"]

MAX_COMMENT_PARAMS = 14          # parameters listed per entry in the comments (a rigid-body step has dozens)


@dataclass
class PatchEntry:
    """One step of the diagnosis as seen by the patch: its twin-config ``fragment`` (``None``: not in the patch)
    and the ``comment`` lines that explain it."""
    name: str
    fragment: dict[str, Any] | None
    comment: list[str]


def _param_lines(theta: np.ndarray, ci: np.ndarray, names: list[str]) -> list[str]:
    """Fitted values ± 95 % CI, one line per per-joint parameter (``key[j]`` names) or one line for the first
    :data:`MAX_COMMENT_PARAMS` others."""
    groups: dict[str, list[str]] = {}
    for nm, v, c in zip(names, theta, ci):
        key = nm.split("[")[0] if nm.endswith("]") else ""
        groups.setdefault(key, []).append(f"{v:.4g} ± {c:.2g}" if key else f"{nm} = {v:.4g} ± {c:.2g}")
    out = [f"  {k}: [{', '.join(v)}]" for k, v in groups.items() if k]
    if "" in groups:
        items = groups[""]
        more = len(items) - MAX_COMMENT_PARAMS
        out.append("  " + ", ".join(items[:MAX_COMMENT_PARAMS]) + (f", … ({more} more)" if more > 0 else ""))
    return out


class _Dumper(yaml.SafeDumper):
    """``yaml.safe_dump`` with lists of numbers on one line (per-joint vectors stay readable)."""


class _RoundingDumper(_Dumper):
    """:class:`_Dumper` writing floats to 7 significant digits (far below every fitted parameter's CI; not for
    inertials, whose physical consistency may sit at the rounding level)."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(x, (int, float)) for x in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


def _represent_float(dumper: yaml.SafeDumper, data: float) -> yaml.Node:
    return dumper.represent_float(float(f"{data:.7g}"))


_Dumper.add_representer(list, _represent_list)
_RoundingDumper.add_representer(float, _represent_float)


def _dump(data: dict[str, Any], rounding: bool = True) -> str:
    return yaml.dump(data, Dumper=_RoundingDumper if rounding else _Dumper, sort_keys=False, allow_unicode=True,
                     width=120)


def undetermined_load_gains(theta: np.ndarray, ci: np.ndarray, names: list[str]) -> tuple[np.ndarray, list[str]]:
    """``theta`` with every load-dependent friction gain (a parameter named ``load_gain[...]``) whose 95 % CI ``ci``
    holds 0 set to 0 (its nominal value), and the names so set."""
    zero = np.array([nm.split("[")[0] == "load_gain" for nm in names], dtype=bool) & (np.abs(theta) <= ci)
    zero &= theta != 0.0
    return np.where(zero, 0.0, theta), [nm for nm, z in zip(names, zero) if z]


def patch_entries(att: Attribution) -> list[PatchEntry]:
    """Every accepted step and noise finding of ``att`` as a :class:`PatchEntry` (processing steps with
    ``fragment=None``)."""
    final = att.steps[-1].params if att.steps else {}
    out = []
    for step in att.steps:
        head = f"{step.name}: held-out gain {100 * step.gain:.1f} % (t = {step.t_stat:.1f} over blocks)"
        if step.tied:
            head += f"; tied with {', '.join(step.tied)} (the data cannot separate them)"
        if step.processing:
            out.append(PatchEntry(step.name, None, [f"{head} — not in the patch: data path, not the robot "
                                                    f"({step.reason})"]))
            continue
        cand = att.fitted.get(step.name)
        if cand is None or step.name not in final:
            out.append(PatchEntry(step.name, None, [f"{head} — not in the patch: its fit was not kept"]))
            continue
        theta, ci, names = final[step.name]
        cand.patch_note = ""
        kept, zeroed = undetermined_load_gains(np.asarray(theta, dtype=float), np.asarray(ci, dtype=float), names)
        frag = cand.patch(kept)
        lines = [head + "; fitted ± 95 % CI:", *_param_lines(np.asarray(theta), np.asarray(ci), names)]
        if zeroed:
            lines.append(f"  {', '.join(zeroed)}: not told apart from 0 by the data (the 95 % CI holds 0), 0 in the "
                         "patch — the nominal value, as the rigid-body correction keeps unidentified directions at "
                         "theirs (a twin checks a load gain's friction at the joints' effort limits)")
        if cand.patch_note:
            lines.append(f"  {cand.patch_note}")
        if frag is None and not cand.patch_note:
            lines.append("  not in the patch: the twin cannot express this candidate")
        out.append(PatchEntry(step.name, frag, lines))
    for f in att.noise:
        if f.name != "torque_noise":
            continue
        std = np.asarray(f.rms, dtype=float)
        if not np.any(std > 0):
            continue
        out.append(PatchEntry(f.name, {"effects": {"torque_noise": {"std": std.tolist()}}},
                              [f"torque_noise: {f.explanation}; σ = {np.array2string(std, precision=3)} N·m "
                               "(white: no held-out gain by construction)"]))
    return out


_ABSENT = object()          # a key a fragment's description lacks (or a base lacks)


def _leaf_changes(base: Any, new: Any, path: tuple = ()) -> dict[tuple, Any]:
    """The leaves where ``new`` (a description mapping) differs from ``base``: ``{path: new value}``, a path being
    the keys and list indices from the top (a list whose length changed, or a value whose type changed, is one
    leaf; a key ``new`` drops maps to :data:`_ABSENT`)."""
    if isinstance(base, dict) and isinstance(new, dict):
        out: dict[tuple, Any] = {}
        for k in dict.fromkeys([*base, *new]):
            out.update(_leaf_changes(base.get(k, _ABSENT), new.get(k, _ABSENT), path + (k,)))
        return out
    if isinstance(base, list) and isinstance(new, list) and len(base) == len(new):
        out = {}
        for i, (b, v) in enumerate(zip(base, new)):
            out.update(_leaf_changes(b, v, path + (i,)))
        return out
    return {} if _same(base, new) else {path: new}


def _same(a: Any, b: Any) -> bool:
    """Equal leaves (numbers to 1e-12 relative: the same base written twice may differ in the last bit)."""
    if a is _ABSENT or b is _ABSENT:
        return a is b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return bool(np.isclose(a, b, rtol=1e-12, atol=0.0, equal_nan=True))
    if isinstance(a, (dict, list)) or isinstance(b, (dict, list)):
        return not _leaf_changes(a, b) if type(a) is type(b) else False
    return a == b


def _path_text(path: tuple) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


def _apply(into: Any, path: tuple, value: Any) -> None:
    for p in path[:-1]:
        into = into[p]
    if value is _ABSENT:
        del into[path[-1]]
    else:
        into[path[-1]] = value


@dataclass
class MergedPatch:
    """The twin patch of a diagnosis (:func:`merge_entries`): ``patch`` the twin-config fragment, ``unmerged`` one
    line per change that could not be merged (two entries setting the same leaf to different values: the first
    entry's value is kept)."""
    patch: dict[str, Any]
    unmerged: list[str]


def merge_entries(entries: list[PatchEntry], model: SimModel) -> MergedPatch:
    """Every entry's fragment merged into one patch. Effect blocks merge key by key; the ``robot:`` fragments —
    each a full description mapping built from ``model.robot`` by one step (rigid body, rotor inertia, motor
    friction, drive offsets...) — merge as their changes against that base description, leaf by leaf, into ONE
    corrected description. Two entries changing the same leaf (or effect key, or a top-level key such as
    ``payload``) to different values is a true conflict: the first entry's value is kept and the conflict is a line
    of :attr:`MergedPatch.unmerged` (never an error: the diagnosis keeps its answer)."""
    model = SimModel.of(model)
    base_robot = model.robot.to_dict()
    base_robot["name"] = model.robot.name
    out: dict[str, Any] = {"patch_for": {"robot": model.robot.name, "joints": model.robot.n}}
    owner: dict[tuple, tuple[str, Any]] = {}           # leaf path (top key first) -> (entry, value)
    robot: dict[str, Any] | None = None
    unmerged: list[str] = []

    def claim(path: tuple, value: Any, who: str) -> bool:
        if path in owner:
            first, kept = owner[path]
            if not _same(kept, value):
                unmerged.append(f"{who} sets {_path_text(path)} to {_short(value)}, {first} to {_short(kept)}: "
                                f"{first}'s kept")
            return False
        owner[path] = (who, value)
        return True

    for e in entries:
        for key, value in (e.fragment or {}).items():
            if key == "effects":
                eff = out.setdefault("effects", {})
                for name, block in value.items():
                    for k, v in block.items():
                        if claim(("effects", name, k), v, e.name):
                            eff.setdefault(name, {})[k] = v
            elif key == "robot" and isinstance(value, dict):
                robot = copy.deepcopy(base_robot) if robot is None else robot
                for path, v in _leaf_changes(base_robot, value).items():
                    if claim(("robot",) + path, v, e.name):
                        _apply(robot, path, copy.deepcopy(v))
            elif claim((key,), value, e.name):
                out[key] = value
    if robot is not None:
        out["robot"] = robot
    return MergedPatch(out, unmerged)


def _short(value: Any) -> str:
    text = repr(value) if value is not _ABSENT else "nothing (removed)"
    return text if len(text) <= 60 else text[:57] + "..."


def twin_patch(att: Attribution, model: SimModel, entries: list[PatchEntry] | None = None) -> dict[str, Any]:
    """The twin-config fragment of a diagnosis: ``patch_for: {robot, joints}`` plus the ``effects`` / ``payload`` /
    ``robot`` (a description mapping) of the physical steps (module docstring; merged by :func:`merge_entries`).
    ``entries``: precomputed :func:`patch_entries` (the rigid-body mapping solves an SDP; compute it once)."""
    return merge_entries(entries if entries is not None else patch_entries(att), model).patch


def write_twin_patch(att: Attribution, model: SimModel, path: str | Path,
                     entries: list[PatchEntry] | None = None, merged: MergedPatch | None = None) -> dict[str, Path]:
    """Write ``path`` (``twin_patch.yaml``: comments + the YAML of a ``yaml.SafeDumper``, atomic) and, when the
    patch corrects the rigid body, ``<stem>_robot.yaml`` beside it (the patch's ``robot:`` names it relative to its
    folder). Returns ``{"twin_patch": path[, "patch_robot": robot path]}``; ``entries`` as in :func:`twin_patch`;
    ``merged``: their :func:`merge_entries`, when already computed (left unchanged)."""
    model = SimModel.of(model)
    path = Path(path)
    entries = entries if entries is not None else patch_entries(att)
    merged = merged if merged is not None else merge_entries(entries, model)
    patch = dict(merged.patch)                  # the robot becomes a file name here, not in ``merged``
    files = {"twin_patch": path}
    if isinstance(patch.get("robot"), dict):
        robot_path = path.with_name(f"{path.stem}_robot.yaml")
        atomic_write_text(robot_path, f"# {model.robot.name} as corrected by proprio diagnose "
                                      f"(see {path.name})\n" + _dump(patch["robot"], rounding=False))
        patch["robot"] = robot_path.name
        files["patch_robot"] = robot_path
    head = [f"twin patch of a gap diagnosis of '{model.robot.name}' ({model.robot.n} joints); model: "
            + (", ".join(sorted(model.effect_names)) or "rigid body only"),
            "apply: proprio simulate --twin BASE --patch THIS_FILE ... (BASE: a twin config of this robot without "
            "these effects)",
            "each entry: held-out gain of its step, fitted parameters (final joint fit) with 95 % CI, SI units"]
    for e in entries:
        head.extend(e.comment)
    head.extend(f"not merged (a conflict: two entries change the same value): {line}" for line in merged.unmerged)
    if all(e.fragment is None for e in entries):
        head.append("nothing physical was found: the patch changes nothing")
    text = "".join(f"# {line}\n" for line in head) + _dump(patch)
    atomic_write_text(path, text)
    return files


@dataclass(frozen=True)
class Patch:
    """The diagnosis as a twin patch: its ``entries``, the patch itself (``twin_patch``, the mapping a base twin's
    config is merged with; a rigid-body or drive correction as a robot mapping), the ``files`` written
    (:func:`write_twin_patch`) and the ``unmerged`` conflicts (:attr:`MergedPatch.unmerged`)."""
    entries: list[PatchEntry]
    twin_patch: dict[str, Any]
    files: dict[str, Path]
    unmerged: list[str]


def make_patch(att: Attribution, model: SimModel, path: str | Path) -> Patch:
    """The patch of ``att`` for ``model``, written to ``path`` (``twin_patch.yaml``, :func:`write_twin_patch`)."""
    entries = patch_entries(att)
    merged = merge_entries(entries, model)
    files = write_twin_patch(att, model, path, entries, merged)
    return Patch(entries, merged.patch, files, merged.unmerged)

