"""``proprio import``: turn a robot's own log files (CSV/TXT) into a Recording, driven by a small mapping YAML.

A log comes as one table or one file per channel, with or without a header row, any delimiter (``,``, ``;``, tab,
``|`` or white space) and a decimal point or comma. The mapping (``format: proprio-import/v1``, keys checked
strictly) says which columns are the time, joint angles q, velocities q̇ and torques τ, in which units, and on which
side of the gears they were measured:

* ``q``/``qd``: ``unit`` rad | deg | counts (``counts_per_rev`` of the encoder); ``side`` joint | motor.
* ``tau``: ``quantity`` joint_torque [N·m at the joint] | motor_torque [N·m at the motor] | motor_current [A,
  times ``drive.torque_constant`` N·m/A].
* ``drive``: ``gear_ratio`` N_i per joint and optional ``coupling`` entries ``{motor, joint, ratio}`` (1-based), which
  make the motor↔joint matrix R with ``q_motor = R q`` (R = diag(N) plus the couplings, e.g. the TX40's motor 6
  turning with joint 5: R[6,5] = N₆). Motor-side channels become joint-side ones as ``q = R⁻¹ q_motor`` and
  ``τ = Rᵀ τ_motor`` (DESIGN.md "Arms without joint-torque sensors").
* ``q_offset`` [rad] (or ``q_offset_deg``): the encoder zero vs the robot model's zero, added on the joint side.
* ``rate_hz``: the sample rate when there is no ``time`` channel (then t = k / rate).
* ``tau_kind``: ``link_sensor`` (a joint-torque sensor behind the gear) or ``drive`` (drive torque from currents,
  which still holds rotor inertia, motor friction and offsets); written to the Recording's ``meta.tau_kind``.

Everything is vectorised over samples; file paths in the mapping are relative to ``data_dir`` (default: the mapping
file's folder).
"""
from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from proprio.description import check_keys
from proprio.recording import Recording, RecordingError, merge_duplicate_stamps, validate_recording

__all__ = ["LogImportError", "ImportMapping", "load_mapping", "read_table", "import_recording", "TAU_KINDS"]

TAU_KINDS = ("link_sensor", "drive")
_DELIMITERS = (";", "\t", "|", ",")   # sniffing order: a decimal comma file is ;- or tab-separated
_TOP_KEYS = ("format", "robot", "joints", "file", "read", "rate_hz", "time", "q", "qd", "tau", "drive", "q_offset",
             "q_offset_deg", "tau_kind", "note")
_READ_KEYS = ("delimiter", "decimal", "header", "skip_rows")
_CHANNEL_KEYS = {"time": ("file", "column", "unit"),
                 "q": ("file", "columns", "unit", "side", "counts_per_rev"),
                 "qd": ("file", "columns", "unit", "side", "counts_per_rev"),
                 "tau": ("file", "columns", "quantity")}
_DRIVE_KEYS = ("gear_ratio", "coupling", "torque_constant")
_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_TAU_QUANTITIES = ("joint_torque", "motor_torque", "motor_current")


class LogImportError(RecordingError):
    """A mapping or a log file cannot be imported; the message names the field or file."""


@dataclass(frozen=True)
class ImportMapping:
    """A validated mapping YAML (see the module docstring); ``raw`` is the checked mapping, ``source`` its path."""
    raw: dict[str, Any]
    source: str
    n: int


def _fail(where: str, msg: str) -> LogImportError:
    return LogImportError(f"{where}: {msg}")


def _floats(value: Any, size: int, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise _fail(where, f"expected {size} numbers, got {value!r}") from exc
    if arr.size != size:
        raise _fail(where, f"expected {size} numbers (one per joint), got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise _fail(where, f"non-finite value in {value!r}")
    return arr


def load_mapping(path: str | Path) -> ImportMapping:
    """Read and check a ``proprio-import/v1`` mapping YAML (unknown keys are errors naming the nearest valid key)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise _fail(str(path), f"cannot read the mapping ({exc.strerror})") from exc
    except yaml.YAMLError as exc:
        raise _fail(str(path), f"invalid YAML ({exc})") from exc
    src = str(path)
    if not isinstance(data, dict):
        raise _fail(src, "top level must be a mapping")
    check_keys(data, _TOP_KEYS, src)
    fmt = data.get("format", "proprio-import/v1")
    if fmt != "proprio-import/v1":
        raise _fail(f"{src}:format", f"expected 'proprio-import/v1', got {fmt!r}")
    if isinstance(data.get("joints"), bool) or not isinstance(data.get("joints"), int) or data["joints"] < 1:
        raise _fail(f"{src}:joints", "the number of joints (a positive integer) is required, got "
                                     f"{data.get('joints')!r}")
    n = int(data["joints"])
    read = data.get("read") or {}
    if not isinstance(read, dict):
        raise _fail(f"{src}:read", f"expected a mapping with {list(_READ_KEYS)}, got {read!r}")
    check_keys(read, _READ_KEYS, f"{src}:read")
    skip = read.get("skip_rows", 0)
    if isinstance(skip, bool) or not isinstance(skip, int) or skip < 0:
        raise _fail(f"{src}:read.skip_rows", f"must be an integer >= 0, got {skip!r}")
    for name, keys in _CHANNEL_KEYS.items():
        ch = data.get(name)
        if ch is None:
            continue
        if not isinstance(ch, dict):
            raise _fail(f"{src}:{name}", f"expected a mapping with {list(keys)}")
        check_keys(ch, keys, f"{src}:{name}")
    for name in ("q", "tau"):
        if name not in data:
            raise _fail(src, f"missing channel '{name}' (a Recording needs q and tau)")
    if "time" not in data and "rate_hz" not in data:
        raise _fail(src, "no 'time' channel and no 'rate_hz': give one of them")
    if "rate_hz" in data:
        rate = data["rate_hz"]
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
            raise _fail(f"{src}:rate_hz", f"must be a positive number [Hz], got {rate!r}")
    drive = data.get("drive")
    if drive is not None:
        if not isinstance(drive, dict):
            raise _fail(f"{src}:drive", "expected a mapping with gear_ratio, coupling, torque_constant")
        check_keys(drive, _DRIVE_KEYS, f"{src}:drive")
    tau_kind = data.get("tau_kind", "link_sensor")
    if tau_kind not in TAU_KINDS:
        raise _fail(f"{src}:tau_kind", f"must be one of {list(TAU_KINDS)}, got {tau_kind!r}")
    mapping = ImportMapping(raw=data, source=src, n=n)
    _motor_matrix(mapping)   # checks gear ratios and couplings up front
    return mapping


def _motor_matrix(m: ImportMapping) -> np.ndarray | None:
    """R with ``q_motor = R q`` (None when the mapping has no ``drive`` block)."""
    drive = m.raw.get("drive")
    if drive is None:
        return None
    where = f"{m.source}:drive"
    if "gear_ratio" not in drive:
        raise _fail(where, "missing field 'gear_ratio' (one per joint)")
    ratio = _floats(drive["gear_ratio"], m.n, f"{where}.gear_ratio")
    if np.any(ratio == 0):
        raise _fail(f"{where}.gear_ratio", "a gear ratio of 0 is not invertible")
    r = np.diag(ratio)
    for k, c in enumerate(drive.get("coupling") or []):
        cw = f"{where}.coupling[{k}]"
        if not isinstance(c, dict):
            raise _fail(cw, "expected a mapping {motor, joint, ratio} (1-based indices)")
        check_keys(c, ("motor", "joint", "ratio"), cw)
        i, j = c.get("motor"), c.get("joint")
        if not all(isinstance(x, int) and 1 <= x <= m.n for x in (i, j)) or i == j:
            raise _fail(cw, f"motor and joint must be distinct indices in 1..{m.n}, got {i!r}, {j!r}")
        r[i - 1, j - 1] = _floats([c.get("ratio")], 1, f"{cw}.ratio")[0]
    if np.linalg.cond(r) > 1e12:
        raise _fail(where, "the motor↔joint matrix is singular")
    return r


# ---- reading tables -------------------------------------------------------------------------------------

def _is_number(text: str, decimal: str) -> bool:
    text = text.strip()
    if decimal == ",":
        text = text.replace(",", ".")
    try:
        float(text)
    except ValueError:
        return False
    return True


def _split(line: str, delimiter: str | None) -> list[str]:
    return line.split() if delimiter is None else line.split(delimiter)


def _sniff_delimiter(lines: list[str]) -> str | None:
    """The delimiter that splits the sample lines into the same number (> 1) of fields; None = white space."""
    for d in _DELIMITERS:
        counts = {len(line.split(d)) for line in lines}
        if len(counts) == 1 and counts.pop() > 1:
            return d
    return None


def read_table(path: str | Path, delimiter: str = "auto", decimal: str = "auto", header: str | bool = "auto",
               skip_rows: int = 0) -> tuple[list[str] | None, np.ndarray]:
    """Read a numeric text table. Returns ``(column names or None, data [N, m])``.

    ``delimiter``: ``auto`` (sniffed from the first lines), one of ``, ; \\t |`` or ``whitespace``; ``decimal``:
    ``auto`` (a comma when the delimiter is not a comma and the numbers carry one), ``.`` or ``,``; ``header``:
    ``auto`` (the first row holds a non-number), ``true`` or ``false``; ``skip_rows`` lines are dropped first."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(str(path), f"cannot read the log file ({exc})") from exc
    lines = [ln for ln in text.splitlines()[skip_rows:] if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise _fail(str(path), "no data rows")
    sample = lines[1:21] if len(lines) > 1 else lines
    if delimiter == "auto":
        delim = _sniff_delimiter(sample)
    elif delimiter == "whitespace":
        delim = None
    elif delimiter in _DELIMITERS or delimiter == "\\t":
        delim = "\t" if delimiter == "\\t" else delimiter
    else:
        raise _fail(f"{path}: read.delimiter", f"one of auto, ',', ';', '\\t', '|', whitespace; got {delimiter!r}")
    if decimal == "auto":
        decimal = "," if delim != "," and any(re.search(r"\d,\d", ln) for ln in sample) else "."
    if decimal not in (".", ","):
        raise _fail(f"{path}: read.decimal", f"'.' or ',', got {decimal!r}")
    if decimal == "," and delim == ",":
        raise _fail(str(path), "decimal comma with a comma delimiter is ambiguous; set read.delimiter")
    first = [f.strip().strip('"') for f in _split(lines[0], delim)]
    has_header = (not all(_is_number(f, decimal) for f in first)) if header == "auto" else bool(header)
    body = lines[1:] if has_header else lines
    if not body:
        raise _fail(str(path), "a header but no data rows")
    joined = "\n".join(body)
    if decimal == ",":
        joined = joined.replace(",", ".")
    try:
        data = np.loadtxt(io.StringIO(joined), delimiter=delim, ndmin=2, dtype=float, quotechar='"')
    except ValueError as exc:
        raise _fail(str(path), f"not a numeric table ({exc}); check read.delimiter/decimal/header") from exc
    return (first if has_header else None), data


# ---- assembling a Recording -----------------------------------------------------------------------------

def _columns(m: ImportMapping, name: str, data_dir: Path, cache: dict, count: int) -> np.ndarray:
    """The ``count`` columns of channel ``name`` as floats [N, count]."""
    ch = m.raw[name]
    where = f"{m.source}:{name}"
    fname = ch.get("file", m.raw.get("file"))
    if fname is None:
        raise _fail(where, "no 'file' (give it in the channel or at the top level)")
    path = data_dir / str(fname)
    if path not in cache:
        if not path.exists():
            raise _fail(where, f"file {path} not found")
        cache[path] = read_table(path, **{k: v for k, v in (m.raw.get("read") or {}).items()})
    header, data = cache[path]
    spec = ch.get("column") if name == "time" else ch.get("columns")
    if spec is None:
        if data.shape[1] != count:
            raise _fail(where, f"{path.name} has {data.shape[1]} columns; say which {count} with 'columns'")
        return data
    spec = [spec] if not isinstance(spec, list) else spec
    if len(spec) != count:
        raise _fail(where, f"expected {count} column(s), got {len(spec)}")
    idx = []
    for c in spec:
        if isinstance(c, int) and not isinstance(c, bool):
            if not 0 <= c < data.shape[1]:
                raise _fail(where, f"column index {c} outside 0..{data.shape[1] - 1} of {path.name}")
            idx.append(c)
        elif header is not None and str(c) in header:
            idx.append(header.index(str(c)))
        else:
            have = header if header is not None else f"no header; use 0-based indices < {data.shape[1]}"
            raise _fail(where, f"column {c!r} not in {path.name} ({have})")
    return data[:, idx]


def _angle_scale(ch: dict, where: str) -> float:
    unit = ch.get("unit", "rad")
    base = unit[:-2] if unit.endswith("/s") else unit
    if base == "rad":
        return 1.0
    if base == "deg":
        return math.pi / 180.0
    if base == "counts":
        cpr = ch.get("counts_per_rev")
        if isinstance(cpr, bool) or not isinstance(cpr, (int, float)) or not cpr > 0:
            raise _fail(f"{where}.counts_per_rev", f"unit 'counts' needs a positive counts_per_rev, got {cpr!r}")
        return 2.0 * math.pi / float(cpr)
    raise _fail(f"{where}.unit", f"one of rad, deg, counts (with '/s' for velocities), got {unit!r}")


def import_recording(mapping: ImportMapping | str | Path, data_dir: str | Path | None = None,
                     robot_name: str | None = None) -> Recording:
    """Build a validated Recording from the log files a mapping names (joint side, SI units, ``meta.tau_kind``).

    ``data_dir`` (default the mapping's folder) resolves the file names; ``robot_name`` overrides ``robot`` of the
    mapping for ``meta.robot``."""
    m = mapping if isinstance(mapping, ImportMapping) else load_mapping(mapping)
    data_dir = Path(data_dir) if data_dir is not None else Path(m.source).parent
    n, cache = m.n, {}
    r = _motor_matrix(m)
    chans: dict[str, np.ndarray] = {}
    for name in ("q", "qd"):
        if name not in m.raw:
            continue
        ch, where = m.raw[name], f"{m.source}:{name}"
        x = _columns(m, name, data_dir, cache, n) * _angle_scale(ch, where)
        side = ch.get("side", "joint")
        if side == "motor":
            if r is None:
                raise _fail(f"{where}.side", "motor-side channels need a 'drive' block with gear_ratio")
            x = np.linalg.solve(r, x.T).T                          # q = R⁻¹ q_motor
        elif side != "joint":
            raise _fail(f"{where}.side", f"'joint' or 'motor', got {side!r}")
        chans[name] = x
    ch, where = m.raw["tau"], f"{m.source}:tau"
    quantity = ch.get("quantity", "joint_torque")
    if quantity not in _TAU_QUANTITIES:
        raise _fail(f"{where}.quantity", f"one of {list(_TAU_QUANTITIES)}, got {quantity!r}")
    tau = _columns(m, "tau", data_dir, cache, n)
    if quantity == "motor_current":
        kt = (m.raw.get("drive") or {}).get("torque_constant")
        if kt is None:
            raise _fail(f"{m.source}:drive", "motor_current needs 'torque_constant' [N·m/A] per motor")
        tau = tau * _floats(kt, n, f"{m.source}:drive.torque_constant")
    if quantity != "joint_torque":
        if r is None:
            raise _fail(f"{where}.quantity", f"{quantity} needs a 'drive' block with gear_ratio")
        tau = tau @ r                                               # τ = Rᵀ τ_motor, row-wise
    offset_key = "q_offset_deg" if "q_offset_deg" in m.raw else "q_offset"
    if offset_key in m.raw:
        if "q_offset" in m.raw and "q_offset_deg" in m.raw:
            raise _fail(m.source, "both 'q_offset' and 'q_offset_deg' given; keep one")
        off = _floats(m.raw[offset_key], n, f"{m.source}:{offset_key}")
        chans["q"] = chans["q"] + (np.radians(off) if offset_key == "q_offset_deg" else off)
    lengths = {k: v.shape[0] for k, v in (*chans.items(), ("tau", tau))}
    if "time" in m.raw:
        tw = f"{m.source}:time"
        unit = m.raw["time"].get("unit", "s")
        if unit not in _TIME_UNITS:
            raise _fail(f"{tw}.unit", f"one of {list(_TIME_UNITS)}, got {unit!r}")
        t = _columns(m, "time", data_dir, cache, 1)[:, 0] * _TIME_UNITS[unit]
        lengths["time"] = t.shape[0]
    if len(set(lengths.values())) != 1:
        raise _fail(m.source, f"channels have different lengths {lengths}")
    if "time" not in m.raw:
        t = np.arange(lengths["q"]) / float(m.raw["rate_hz"])
    meta: dict[str, Any] = {
        "source": f"proprio import of {Path(m.source).name}", "tau_kind": m.raw.get("tau_kind", "link_sensor"),
        "import": {"files": sorted(str(p.name) for p in cache), "tau_quantity": quantity}}
    if r is not None:
        meta["import"]["motor_matrix"] = r.tolist()
    name = robot_name or m.raw.get("robot")
    if name:
        meta["robot"] = str(name)
    rec = Recording(t=t - t[0], q=chans["q"], tau=tau, qd=chans.get("qd"), meta=meta)
    rec = validate_recording(merge_duplicate_stamps(rec), source=m.source)
    rec.meta["rate_hz"] = rec.rate_hz
    return rec
