"""The Recording: proprio's one data format (DESIGN.md), with validating loaders and atomic writers.

A Recording holds a joint-space time series of one arm:

* ``t [N]`` s, strictly increasing;
* ``q [N,n]`` rad (a degree-valued ``q`` is rejected, never guessed);
* ``tau [N,n]`` N·m — the measured link-side joint torque τ_J;
* optional ``qd``, ``qdd [N,n]`` (rad/s, rad/s²), ``f_ext [N,6]`` — the true external wrench exerted on the robot
  at the flange origin, world frame, order ``[fx, fy, fz, mx, my, mz]`` (N, N·m);
* ``truth``: extra channels (``tau_rbd``, ``tau_<effect>``, ...), each with first dimension N;
* ``meta``: a JSON-serialisable dict (robot, rate_hz, source, payload, effects, seed, ...).

On disk it is an ``.npz`` (``allow_pickle=False``) with keys ``t, q, tau[, qd, qdd, f_ext]``, ``truth__<name>`` and
``meta`` (a JSON string). CSV import (:func:`recording_from_csv`) and the real KUKA LWR 4+ files
(:func:`load_lwr4`) are converted at the boundary.

Plausibility (with a robot): a measured ``|τ|`` or ``|q̇|`` beyond :data:`PLAUSIBLE_LIMIT_FACTOR` times the robot's
effort or velocity limit is no reading of that robot (a wrong unit, a corrupt file, a sensor fault) and is refused by
the loader, naming the channel, joint and sample, before any stage runs; between the limit and that factor the data
are kept and ``proprio inspect`` reports them (``over_limit``), and values sitting *at* the limit are clipping.
"""
from __future__ import annotations

import dataclasses
import json
import re
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proprio.description import RobotDescription, load_robot
from proprio.io import atomic_path

__all__ = ["Recording", "RecordingError", "save_recording", "load_recording", "validate_recording",
           "recording_from_csv", "merge_duplicate_stamps", "load_lwr4", "is_lwr4_file", "LWR4_KEYS",
           "check_plausible", "PLAUSIBLE_LIMIT_FACTOR", "is_bag", "BAG_SUFFIXES"]

TRUTH_PREFIX = "truth__"
LWR4_KEYS = frozenset({"times", "positions", "torques"})   # FloBaRoID's measurement layout
_OPTIONAL = ("qd", "qdd", "f_ext")
TEXT_LOG_SUFFIXES = (".csv", ".txt", ".tsv", ".dat")
IMPORT_HINT = ("convert it with `proprio import MAPPING.yaml --out REC.npz` (a mapping says which columns are q, τ, "
               "units, gear ratios; example: proprio/configs/import_tx40.yaml)")
BAG_SUFFIXES = (".bag", ".mcap", ".db3")   # what proprio.bag_import reads (and ROS 2 bag folders)
PLAUSIBLE_LIMIT_FACTOR = 3.0
"""Measured ``|τ|`` / ``|q̇|`` above this multiple of the robot's effort / velocity limit are refused (module
docstring): a drive's peak torque may exceed its rated limit, but not several times over."""


class RecordingError(ValueError):
    """A Recording (or a file meant to be one) is invalid; the message names the offending field."""


def is_bag(path: str | Path) -> bool:
    """True for what :func:`proprio.bag_import.import_bag` reads: a ``.bag``/``.mcap``/``.db3`` file or a folder
    with ``metadata.yaml`` (a ROS 2 bag)."""
    p = Path(path)
    return p.suffix.lower() in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").exists())


@dataclass
class Recording:
    """A measured or simulated joint-space time series; see the module docstring for units and frames."""
    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    f_ext: np.ndarray | None = None
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def duration(self) -> float:
        """Time span [s]."""
        return float(self.t[-1] - self.t[0]) if self.n_samples > 1 else 0.0

    @property
    def rate_hz(self) -> float:
        """Sample rate [Hz] from the median time step."""
        return float(1.0 / np.median(np.diff(self.t))) if self.n_samples > 1 else float("nan")

    def slice(self, i0: int, i1: int) -> "Recording":
        """Samples ``i0:i1`` (a view-free copy of every channel, meta shared)."""
        cut = lambda a: None if a is None else np.array(a[i0:i1])  # noqa: E731
        return Recording(t=cut(self.t), q=cut(self.q), tau=cut(self.tau), qd=cut(self.qd), qdd=cut(self.qdd),
                         f_ext=cut(self.f_ext), truth={k: cut(v) for k, v in self.truth.items()},
                         meta=dict(self.meta))

    def downsample(self, step: int) -> "Recording":
        """Every ``step``-th sample of every channel (no anti-alias filter: the caller decides), ``meta.rate_hz``
        updated."""
        if step < 1:
            raise RecordingError(f"downsample: step must be >= 1, got {step}")
        return self.take(np.arange(0, self.n_samples, step))

    def take(self, index: np.ndarray) -> "Recording":
        """The samples at the increasing indices ``index`` of every channel (copies), ``meta.rate_hz`` updated."""
        pick = lambda a: None if a is None else np.array(a[index])  # noqa: E731
        rec = Recording(t=pick(self.t), q=pick(self.q), tau=pick(self.tau), qd=pick(self.qd), qdd=pick(self.qdd),
                        f_ext=pick(self.f_ext), truth={k: pick(v) for k, v in self.truth.items()},
                        meta=dict(self.meta))
        rec.meta["rate_hz"] = rec.rate_hz
        return rec

    def replace(self, **changes: Any) -> "Recording":
        return dataclasses.replace(self, **changes)


def _check_array(name: str, a: Any, shape: tuple[int | None, ...], source: str) -> np.ndarray:
    kind = np.asarray(a).dtype.kind
    if kind not in "biuf":          # text, complex, objects, dates: never converted silently
        raise RecordingError(f"{source}: '{name}' is not real numbers (dtype {np.asarray(a).dtype})")
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"{source}: '{name}' is not numeric ({exc})") from exc
    if arr.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, arr.shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise RecordingError(f"{source}: '{name}' has shape {list(arr.shape)}, expected {want}")
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = np.argwhere(bad)[0]
        kind = "NaN" if np.isnan(arr[tuple(idx)]) else "inf"
        raise RecordingError(f"{source}: '{name}' contains {int(bad.sum())} non-finite value(s) ({kind} first at "
                             f"sample {int(idx[0])})")
    return arr


def validate_recording(rec: Recording, robot: RobotDescription | None = None, source: str = "recording") -> Recording:
    """Check shapes, finiteness, strictly increasing time, radians, and (with ``robot``) the joint count and position
    limits. Returns ``rec`` with float64 arrays; raises :class:`RecordingError` naming the problem."""
    t = _check_array("t", rec.t, (None,), source)
    n_s = t.shape[0]
    if n_s < 2:
        raise RecordingError(f"{source}: 't' has {n_s} sample(s); a Recording needs at least 2")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise RecordingError(f"{source}: 't' is not strictly increasing (t[{k + 1}] = {t[k + 1]:.6g} s <= "
                             f"t[{k}] = {t[k]:.6g} s)")
    q = _check_array("q", rec.q, (n_s, None), source)
    n = q.shape[1]
    if n == 0:
        raise RecordingError(f"{source}: 'q' has no joint columns")
    tau = _check_array("tau", rec.tau, (n_s, n), source)
    opt = {}
    for name in _OPTIONAL:
        val = getattr(rec, name)
        opt[name] = None if val is None else _check_array(name, val, (n_s, 6 if name == "f_ext" else n), source)
    truth = {}
    for k, v in rec.truth.items():
        arr = np.asarray(v)
        if arr.ndim == 0 or arr.shape[0] != n_s:
            raise RecordingError(f"{source}: truth channel '{k}' has shape {list(arr.shape)}, first dimension must "
                                 f"be N = {n_s}")
        truth[k] = _check_array(f"truth.{k}", arr, arr.shape, source)
    # radians: a joint whose range exceeds 2π over a normal recording is degree-valued (or wrapped): reject
    span = np.abs(q).max(axis=0)
    if np.any(span > 2 * np.pi + 1e-6):
        j = int(np.argmax(span))
        raise RecordingError(f"{source}: 'q' joint {j} reaches {span[j]:.1f} — larger than 2π rad; q must be in radians "
                             "(convert degrees with np.radians)")
    if robot is not None:
        if n != robot.n:
            raise RecordingError(f"{source}: 'q' has {n} joints but robot '{robot.name}' has {robot.n}")
        tol = np.radians(0.5)
        lo, hi = robot.lower - tol, robot.upper + tol
        viol = (q < lo) | (q > hi)
        if viol.any():
            i, j = (int(x) for x in np.argwhere(viol)[0])
            raise RecordingError(f"{source}: 'q' joint {j} ({robot.joint_names[j]}) = {q[i, j]:.4f} rad at sample {i} "
                                 f"is outside the limits [{robot.lower[j]:.4f}, {robot.upper[j]:.4f}] rad")
        check_plausible(tau, opt["qd"], robot, source)
    if not isinstance(rec.meta, dict):
        raise RecordingError(f"{source}: 'meta' must be a dict")
    try:  # normalise to what JSON round-trips exactly (tuples -> lists); NaN/inf and odd keys are errors
        meta = json.loads(json.dumps(rec.meta, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"{source}: 'meta' is not strict JSON ({exc})") from exc
    if any(not isinstance(k, str) for k in rec.meta):
        raise RecordingError(f"{source}: 'meta' keys must be strings")
    return Recording(t=t, q=q, tau=tau, truth=truth, meta=meta, **opt)


def check_plausible(tau: np.ndarray, qd: np.ndarray | None, robot: RobotDescription,
                    source: str = "recording") -> None:
    """Refuse measured torques ``tau [N,n]`` N·m or velocities ``qd [N,n]`` rad/s beyond
    :data:`PLAUSIBLE_LIMIT_FACTOR` × ``robot``'s effort / velocity limits (module docstring); raises
    :class:`RecordingError` naming the channel, the joint, the first offending sample and the limit."""
    for name, x, lim, unit, kind in (("tau", tau, robot.effort_limits, "N·m", "effort"),
                                     ("qd", qd, robot.velocity_limits, "rad/s", "velocity")):
        if x is None:
            continue
        ratio = np.abs(x) / lim[None, :]
        bad = ratio > PLAUSIBLE_LIMIT_FACTOR
        if bad.any():
            i, j = (int(v) for v in np.argwhere(bad)[0])
            raise RecordingError(
                f"{source}: '{name}' joint {j} ({robot.joint_names[j]}) = {x[i, j]:.4g} {unit} at sample {i} is "
                f"{ratio[i, j]:.3g}× its {kind} limit {lim[j]:.4g} {unit} ({int(bad.sum())} such value(s)); more "
                f"than {PLAUSIBLE_LIMIT_FACTOR:g}× is no measurement of robot '{robot.name}' (wrong unit, corrupt "
                "file or sensor fault?)")


def save_recording(rec: Recording, path: str | Path) -> Path:
    """Validate and write ``rec`` to ``path`` (``.npz``) atomically. Returns the path."""
    rec = validate_recording(rec, source=str(path))
    path = Path(path)
    if path.suffix != ".npz":
        raise RecordingError(f"{path}: a Recording file must end in .npz")
    arrays: dict[str, np.ndarray] = {"t": rec.t, "q": rec.q, "tau": rec.tau}
    for name in _OPTIONAL:
        if getattr(rec, name) is not None:
            arrays[name] = getattr(rec, name)
    for k, v in rec.truth.items():
        arrays[TRUTH_PREFIX + k] = v
    arrays["meta"] = np.array(json.dumps(rec.meta, sort_keys=True))
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, **arrays)
    return path


def is_lwr4_file(path: str | Path) -> bool:
    """True if ``path`` is an npz in FloBaRoID's measurement layout (``times``, ``positions``, ``torques``)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return LWR4_KEYS <= set(z.files)
    except (OSError, ValueError, zipfile.BadZipFile):
        return False


def load_recording(path: str | Path, robot: RobotDescription | None = None) -> Recording:
    """Load and validate a Recording ``.npz`` (FloBaRoID LWR files are converted via :func:`load_lwr4`).

    Raises :class:`RecordingError` with a one-line message naming the problem (missing file, truncated archive,
    missing key, bad shape, NaN/inf, non-increasing time, degrees, joint count or limits mismatch with ``robot``).
    """
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    if path.suffix.lower() in TEXT_LOG_SUFFIXES:
        raise RecordingError(f"{path}: a text log, not a Recording (.npz); {IMPORT_HINT}")
    if is_bag(path):
        raise RecordingError(f"{path}: a ROS bag, not a Recording (.npz); convert it with `proprio import {path} "
                             "--robot R --out REC.npz`")
    try:
        with np.load(path, allow_pickle=False) as z:
            files = set(z.files)
            if LWR4_KEYS <= files and "t" not in files:
                return _lwr4_from_npz(z, path, robot)
            missing = [k for k in ("t", "q", "tau") if k not in files]
            if missing:
                raise RecordingError(f"{path}: missing key(s) {missing} (a Recording needs t, q, tau)")
            data = {k: z[k] for k in files}
    except RecordingError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, zlib.error) as exc:
        raise RecordingError(f"{path}: not a readable .npz archive (truncated or corrupted: {exc})") from exc
    meta: dict[str, Any] = {}
    if "meta" in data:
        try:
            meta = json.loads(str(data.pop("meta")))
        except json.JSONDecodeError as exc:
            raise RecordingError(f"{path}: 'meta' is not valid JSON ({exc})") from exc
    truth = {k[len(TRUTH_PREFIX):]: v for k, v in data.items() if k.startswith(TRUTH_PREFIX)}
    rec = Recording(t=data["t"], q=data["q"], tau=data["tau"], qd=data.get("qd"), qdd=data.get("qdd"),
                    f_ext=data.get("f_ext"), truth=truth, meta=meta)
    return validate_recording(rec, robot, source=str(path))


def _lwr4_from_npz(z, path: Path, robot: RobotDescription | None) -> Recording:
    t = np.asarray(z["times"], dtype=float)
    rec = Recording(t=t - t[0], q=z["positions"], tau=z["torques"],
                    qd=z["velocities"] if "velocities" in z.files else None,
                    qdd=z["accelerations"] if "accelerations" in z.files else None,
                    meta={"robot": "kuka_lwr4plus", "source": f"FloBaRoID HW measurements ({path.name})",
                          "t0_unix": float(t[0]), "note": "positions/velocities/accelerations/torques are filtered "
                          "upstream (see shared/data/kuka_lwr4/README.md)"})
    rec = validate_recording(rec, robot, source=str(path))
    rec.meta["rate_hz"] = rec.rate_hz
    return rec


def load_lwr4(data_dir: str | Path, index: int) -> Recording:
    """The real KUKA LWR 4+ recording ``measurements_{index}.npz`` in ``data_dir`` (t starts at 0; q, q̇, q̈ and
    τ as filtered upstream; the ``target_*`` keys are ignored — see that folder's README for their logging bug)."""
    data_dir = Path(data_dir)
    path = data_dir / f"measurements_{index}.npz"
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    robot = load_robot(data_dir) if (data_dir / "robot.yaml").exists() else None
    return load_recording(path, robot)  # same checks and one-line errors for corrupted files


def _csv_problem(exc: BaseException, limit: int = 200) -> str:
    """numpy's CSV error in one short phrase: its first bad row and how many more there are (``genfromtxt`` lists
    every bad row: 16 000 characters for a long file), else its message cut to ``limit`` characters."""
    rows = re.findall(r"Line #(\d+) \(got (\d+) columns instead of (\d+)\)", str(exc))
    if rows:
        line, got, want = rows[0]
        more = f"; {len(rows) - 1} more row(s) like it" if len(rows) > 1 else ""
        return f"line {line} has {got} fields where the header has {want}{more}"
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[:limit] + " …"


def recording_from_csv(path: str | Path, n_joints: int, angle_unit: str = "rad", delimiter: str = ",",
                       meta: dict[str, Any] | None = None) -> Recording:
    """Import a CSV with a header row: ``t``, ``q1..qn``, ``tau1..taun`` and optionally ``qd1..``, ``qdd1..``,
    ``fx fy fz mx my mz``. ``angle_unit="deg"`` converts q [°], q̇ [°/s], q̈ [°/s²] to radians at the boundary.
    Rows with the same time stamp as their predecessor are averaged into one sample (:func:`merge_duplicate_stamps`;
    ``meta["duplicate_stamps"]`` says how many), since a Recording's time is strictly increasing."""
    path = Path(path)
    if angle_unit not in ("rad", "deg"):
        raise RecordingError(f"angle_unit must be 'rad' or 'deg', got {angle_unit!r}")
    try:
        table = np.genfromtxt(path, delimiter=delimiter, names=True, dtype=float, encoding="utf-8")
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{path}: cannot parse CSV ({_csv_problem(exc)})") from None
    names = table.dtype.names or ()
    if table.ndim == 0:
        table = table.reshape(1)
    _check_csv_cells(path, table, delimiter)

    def cols(prefix: str, required: bool) -> np.ndarray | None:
        keys = [f"{prefix}{i + 1}" for i in range(n_joints)]
        missing = [k for k in keys if k not in names]
        if missing:
            if required or len(missing) < n_joints:
                raise RecordingError(f"{path}: missing column(s) {missing}")
            return None
        return np.stack([table[k] for k in keys], axis=1)

    if "t" not in names:
        raise RecordingError(f"{path}: missing column 't'")
    scale = np.pi / 180.0 if angle_unit == "deg" else 1.0
    q, qd, qdd = cols("q", True), cols("qd", False), cols("qdd", False)
    wrench = ["fx", "fy", "fz", "mx", "my", "mz"]
    f_ext = np.stack([table[k] for k in wrench], axis=1) if all(k in names for k in wrench) else None
    rec = Recording(t=table["t"], q=q * scale, tau=cols("tau", True), qd=None if qd is None else qd * scale,
                    qdd=None if qdd is None else qdd * scale, f_ext=f_ext,
                    meta={"source": f"csv:{path.name}", **(meta or {})})
    return validate_recording(merge_duplicate_stamps(rec), source=str(path))


def _check_csv_cells(path: Path, table: np.ndarray, delimiter: str) -> None:
    """A cell that is not a number (a word, a decimal comma) is an error naming it, never a NaN in the data."""
    if not table.dtype.names or table.size == 0:
        return
    values = np.column_stack([table[k] for k in table.dtype.names])
    if not np.isnan(values).any():
        return
    try:
        text = np.loadtxt(path, delimiter=delimiter, dtype=str, skiprows=1, ndmin=2, encoding="utf-8")
    except ValueError:                 # ragged rows: the NaN check of the data names the sample
        return
    if text.shape != values.shape:
        return
    bad = np.isnan(values) & ~np.isin(np.char.lower(np.char.strip(text)), ("nan", ""))
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise RecordingError(f"{path}: row {row + 1} column '{table.dtype.names[col]}': '{text[row, col]}' is not "
                             f"a number ({int(bad.sum())} such cell(s); '{delimiter}'-separated, '.' decimals)")


def merge_duplicate_stamps(rec: Recording) -> Recording:
    """Average the samples of every run of equal consecutive time stamps into one sample (every channel, truth
    included) and record what was merged in ``meta["duplicate_stamps"]``: ``stamps`` (merged stamps), ``samples``
    (rows they had) and ``first_t`` [s]. Only *consecutive* duplicates are merged: time that runs backwards stays an
    error for :func:`validate_recording`. Returns ``rec`` itself when there are none."""
    t = np.asarray(rec.t, dtype=float)
    new = np.concatenate([[True], np.diff(t) != 0])                  # first sample of each stamp
    if new.all():
        return rec
    start = np.flatnonzero(new)
    count = np.diff(np.append(start, t.size)).astype(float)

    def mean(a: np.ndarray | None) -> np.ndarray | None:
        if a is None:
            return None
        a = np.asarray(a, dtype=float)
        return np.add.reduceat(a, start, axis=0) / count.reshape((-1,) + (1,) * (a.ndim - 1))

    dup = count > 1
    meta = dict(rec.meta, duplicate_stamps={"stamps": int(dup.sum()), "samples": int(count[dup].sum()),
                                            "first_t": float(t[new][np.argmax(dup)])})
    return Recording(t=t[new], q=mean(rec.q), tau=mean(rec.tau), qd=mean(rec.qd), qdd=mean(rec.qdd),
                     f_ext=mean(rec.f_ext), truth={k: mean(v) for k, v in rec.truth.items()}, meta=meta)
