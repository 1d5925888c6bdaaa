"""The diagnosis as a twin patch: the physical effects a diagnosis found, with their fitted parameters, in the twin
config format (``twin_patch.yaml``), so that ``proprio simulate --twin BASE --patch twin_patch.yaml`` runs the base
twin with them added (:func:`proprio.diagrams.twin.merge_twin_patch`).

Each selected *physical* step contributes its candidate's :meth:`~proprio.diagnosis.candidates.base.Candidate.patch` of
the final joint fit (the last step's ``params``): library effects as ``effects:`` blocks (``sensor_offset`` and
``sensor_gain`` merge into one ``sensor_offset_gain`` block), an unmodelled payload as ``payload:``, a rigid-body
parameter error as a corrected robot description (physically consistent inertials, written as a robot YAML next
to the patch and named by its ``robot:`` key). An unmodelled white noise adds a ``torque_noise`` block — only on
joints whose residual passes both whiteness tests, at the level the raw τ itself carries at the robot's rate
(:func:`proprio.diagnosis.selection.forward.attribute`'s noise finding): a structured residual is never patched as
noise. Data-path (processing) steps never go into a patch; the comments at the top say what was left out and why, and
give each entry's held-out gain and fitted parameters with their 95 % CI.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from proprio.diagnosis.data import DiagnosisError, SimModel
from proprio.diagnosis.attribution import Attribution
from proprio.io import atomic_write_text

__all__ = ["PatchEntry", "Patch", "patch_entries", "twin_patch", "write_twin_patch", "make_patch", "MAX_COMMENT_PARAMS"]

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
        frag = cand.patch(theta)
        lines = [head + "; fitted ± 95 % CI:", *_param_lines(np.asarray(theta), np.asarray(ci), names)]
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


def _merge(into: dict[str, Any], frag: dict[str, Any], where: str) -> None:
    for key, value in frag.items():
        if key == "effects":
            eff = into.setdefault("effects", {})
            for name, block in value.items():
                clash = set(eff.get(name, {})) & set(block)
                if clash:
                    raise DiagnosisError(f"twin patch: {where} sets {name}.{sorted(clash)} a second time")
                eff.setdefault(name, {}).update(block)
        elif key in into:
            raise DiagnosisError(f"twin patch: {where} sets '{key}' a second time")
        else:
            into[key] = value


def twin_patch(att: Attribution, model: SimModel, entries: list[PatchEntry] | None = None) -> dict[str, Any]:
    """The twin-config fragment of a diagnosis: ``patch_for: {robot, joints}`` plus the ``effects`` / ``payload`` /
    ``robot`` (a description mapping) of the physical steps (module docstring). ``entries``: precomputed
    :func:`patch_entries` (the rigid-body mapping solves an SDP; compute it once)."""
    model = SimModel.of(model)
    out: dict[str, Any] = {"patch_for": {"robot": model.robot.name, "joints": model.robot.n}}
    for e in entries if entries is not None else patch_entries(att):
        if e.fragment is not None:
            _merge(out, e.fragment, e.name)
    return out


def write_twin_patch(att: Attribution, model: SimModel, path: str | Path,
                     entries: list[PatchEntry] | None = None) -> dict[str, Path]:
    """Write ``path`` (``twin_patch.yaml``: comments + the YAML of a ``yaml.SafeDumper``, atomic) and, when the
    patch corrects the rigid body, ``<stem>_robot.yaml`` beside it (the patch's ``robot:`` names it relative to its
    folder). Returns ``{"twin_patch": path[, "patch_robot": robot path]}``; ``entries`` as in :func:`twin_patch`."""
    model = SimModel.of(model)
    path = Path(path)
    entries = entries if entries is not None else patch_entries(att)
    patch = twin_patch(att, model, entries)
    files = {"twin_patch": path}
    if isinstance(patch.get("robot"), dict):
        robot_path = path.with_name(f"{path.stem}_robot.yaml")
        atomic_write_text(robot_path, f"# {model.robot.name} with the inertials corrected by proprio diagnose "
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
    if all(e.fragment is None for e in entries):
        head.append("nothing physical was found: the patch changes nothing")
    text = "".join(f"# {line}\n" for line in head) + _dump(patch)
    atomic_write_text(path, text)
    return files


@dataclass(frozen=True)
class Patch:
    """The diagnosis as a twin patch: its ``entries``, the patch itself (``twin_patch``, the mapping a base twin's
    config is merged with; a rigid-body correction as a robot mapping) and the ``files`` written
    (:func:`write_twin_patch`)."""
    entries: list[PatchEntry]
    twin_patch: dict[str, Any]
    files: dict[str, Path]


def make_patch(att: Attribution, model: SimModel, path: str | Path) -> Patch:
    """The patch of ``att`` for ``model``, written to ``path`` (``twin_patch.yaml``, :func:`write_twin_patch`)."""
    entries = patch_entries(att)
    files = write_twin_patch(att, model, path, entries)
    return Patch(entries, twin_patch(att, model, entries), files)

