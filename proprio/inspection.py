"""What ``proprio inspect`` reports about a Recording (or a real LWR 4+ file), as plain functions usable from Python and
notebooks: :func:`load_any` (``.npz`` or ``.csv``),
:func:`reversal_counts` (direction reversals of q̇ with a deadband), :func:`summarize_recording` (numbers as a dict),
:func:`format_summary` (the table the CLI prints) and :func:`plot_recording` (q and τ over time).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from proprio.description import RobotDescription
from proprio.io import save_figure
from proprio.recording import (IMPORT_HINT, Recording, RecordingError, load_recording, recording_from_csv,
                              validate_recording)
from proprio.reversals import motion_direction

__all__ = ["DEFAULT_DEADBAND", "load_any", "joint_velocities", "reversal_counts", "summarize_recording",
           "format_summary", "plot_recording"]

DEFAULT_DEADBAND = 0.01
"""Velocity deadband for reversal counting [rad/s] (≈0.6 °/s): slower motion keeps the last direction."""


def joint_velocities(rec: Recording) -> tuple[np.ndarray, str]:
    """The recorded q̇ ``[N,n]`` [rad/s] if present, else central differences of q over t. Returns (q̇, source)."""
    if rec.qd is not None:
        return rec.qd, "recorded"
    return np.gradient(rec.q, rec.t, axis=0), "central differences of q"


def reversal_counts(qd: np.ndarray, deadband: float = DEFAULT_DEADBAND) -> np.ndarray:
    """Number of motion-direction reversals per joint in ``qd [N,n]`` [rad/s].

    The direction of a joint is +1 while ``q̇ > deadband``, −1 while ``q̇ < −deadband`` and keeps its last value
    inside the band (a Schmitt trigger), so noise around a standstill does not count as reversals. A reversal is a
    change between +1 and −1; the first direction a joint takes is not one.
    """
    if deadband < 0:
        raise ValueError(f"deadband must be >= 0 rad/s, got {deadband}")
    held = motion_direction(qd, deadband)
    return np.sum((held[1:] * held[:-1]) < 0, axis=0)


def summarize_recording(rec: Recording, robot: RobotDescription | None = None,
                        deadband: float = DEFAULT_DEADBAND) -> dict[str, Any]:
    """Key figures of ``rec``: duration [s], rate [Hz] (median) with the smallest and largest time step [s], samples,
    and per joint the position range (rad and deg), max |q̇| [rad/s], RMS τ [N·m] and direction reversals per
    second (see :func:`reversal_counts`)."""
    qd, qd_source = joint_velocities(rec)
    n = rec.n_joints
    names = robot.joint_names if robot is not None and robot.n == n else [f"j{i + 1}" for i in range(n)]
    duration = rec.duration
    reversals = reversal_counts(qd, deadband)
    q_min, q_max = rec.q.min(axis=0), rec.q.max(axis=0)
    return {
        "robot": robot.name if robot is not None else rec.meta.get("robot", "?"),
        "source": rec.meta.get("source", "?"),
        "duration_s": duration,
        "rate_hz": rec.rate_hz,
        "dt_min_s": float(np.diff(rec.t).min()),
        "dt_max_s": float(np.diff(rec.t).max()),
        "n_samples": rec.n_samples,
        "n_joints": n,
        "channels": [c for c in ("qd", "qdd", "f_ext") if getattr(rec, c) is not None],
        "truth": sorted(rec.truth),
        "qd_source": qd_source,
        "deadband_rad_s": deadband,
        "joints": names,
        "q_min_rad": q_min,
        "q_max_rad": q_max,
        "q_min_deg": np.degrees(q_min),
        "q_max_deg": np.degrees(q_max),
        "qd_abs_max_rad_s": np.abs(qd).max(axis=0),
        "tau_rms_nm": np.sqrt(np.mean(rec.tau ** 2, axis=0)),
        "reversals": reversals,
        "reversals_per_s": reversals / duration,
    }


def format_summary(summary: dict[str, Any], title: str = "") -> str:
    """The summary as a fixed-width text table (what ``proprio inspect`` prints)."""
    s = summary
    lines = [f"Recording {title}".rstrip(),
             f"  robot: {s['robot']}   source: {s['source']}",
             f"  duration {s['duration_s']:.3f} s   rate {s['rate_hz']:.2f} Hz (dt {1e3 * s['dt_min_s']:.3g}–"
             f"{1e3 * s['dt_max_s']:.3g} ms)   samples {s['n_samples']}   joints {s['n_joints']}",
             f"  optional channels: {', '.join(s['channels']) or '-'}   truth: {', '.join(s['truth']) or '-'}",
             f"  q̇ from {s['qd_source']}; reversals counted with a {s['deadband_rad_s']:g} rad/s deadband",
             ""]
    head = (f"  {'joint':<14}{'q min':>9}{'q max':>9}{'q min':>9}{'q max':>9}{'max|q̇|':>9}{'RMS τ':>9}"
            f"{'rev/s':>8}")
    units = f"  {'':<14}{'[rad]':>9}{'[rad]':>9}{'[deg]':>9}{'[deg]':>9}{'[rad/s]':>9}{'[N·m]':>9}{'[1/s]':>8}"
    lines += [head, units]
    for j, name in enumerate(s["joints"]):
        lines.append(f"  {name:<14}{s['q_min_rad'][j]:9.3f}{s['q_max_rad'][j]:9.3f}{s['q_min_deg'][j]:9.1f}"
                     f"{s['q_max_deg'][j]:9.1f}{s['qd_abs_max_rad_s'][j]:9.3f}{s['tau_rms_nm'][j]:9.3f}"
                     f"{s['reversals_per_s'][j]:8.3f}")
    return "\n".join(lines)


def plot_recording(rec: Recording, path: str | Path, robot: RobotDescription | None = None,
                   title: str = "") -> Path:
    """Write a PNG with joint positions q [rad] and torques τ [N·m] over time t [s] (atomically)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    names = robot.joint_names if robot is not None and robot.n == rec.n_joints else \
        [f"j{i + 1}" for i in range(rec.n_joints)]
    fig, (ax_q, ax_t) = plt.subplots(2, 1, sharex=True, figsize=(10, 6.5), constrained_layout=True)
    for j, name in enumerate(names):
        ax_q.plot(rec.t, rec.q[:, j], lw=1.0, label=name)
        ax_t.plot(rec.t, rec.tau[:, j], lw=1.0, label=name)
    ax_q.set_ylabel("q [rad]")
    ax_t.set_ylabel("τ [N·m]")
    ax_t.set_xlabel("t [s]")
    ax_q.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    for ax in (ax_q, ax_t):
        ax.grid(alpha=0.3)
    ax_q.set_title(title or str(rec.meta.get("source", "recording")))
    return save_figure(fig, path)


def load_any(path: str | Path, robot: RobotDescription | None = None, angle_unit: str = "rad") -> Recording:
    """A Recording from an ``.npz`` (proprio or LWR 4+ layout) or a ``.csv`` (joint count from its ``q<i>``
    header columns; ``angle_unit`` says whether its angles are in rad or deg), validated against ``robot``."""
    path = Path(path)
    if path.suffix.lower() != ".csv":
        return load_recording(path, robot=robot)
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    with path.open(encoding="utf-8") as f:
        header = f.readline()
    n = sum(1 for name in header.split(",") if re.fullmatch(r"q\d+", name.strip()))
    if n == 0:
        raise RecordingError(f"{path}: no 'q1', 'q2', ... columns in the CSV header; for another layout "
                             f"{IMPORT_HINT}")
    try:
        rec = recording_from_csv(path, n, angle_unit=angle_unit)
    except RecordingError as exc:   # e.g. ';'-separated or decimal-comma tables: `proprio import` reads those
        raise RecordingError(f"{exc}; for another layout {IMPORT_HINT}") from exc
    return validate_recording(rec, robot, source=str(path))
