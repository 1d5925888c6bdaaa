"""``proprio import BAG``: turn a ROS bag into a Recording — a ROS 2 bag folder (MCAP or sqlite3 storage), a single
``.mcap`` or ``.db3`` file, or a ROS 1 ``.bag``, read with the pure-Python ``rosbags`` library (no ROS install).

What is read:

* ``sensor_msgs/JointState`` on one topic (``topic``; when the bag has one JointState topic it is taken, when it has
  several the caller must name one): ``position`` [rad] → ``q``, ``effort`` [N·m] → ``tau``, ``velocity`` [rad/s]
  → ``qd`` when every sample has it. Joints are matched **by name** onto the robot description's joint order; joints
  the description lacks (a gripper's) are ignored with a note; a description joint that no message carries is an
  error naming it.
* Messages that carry only some joints (one per controller) are merged by their header stamp: every sample is one
  stamp with every description joint. Stamps at which some joint is missing are dropped with a note.
* The time base is the header stamp (``header.stamp``, the time the controller sampled the state). When the messages
  carry no stamp (0 s), the bag's receive time is the fallback, and the notes say so: receive times carry the
  transport's jitter, which the conditioning's time base (:mod:`proprio.time_base`) then has to undo.
* ``geometry_msgs/WrenchStamped`` on ``wrench_topic`` → ``f_ext [N, 6]`` = ``[fx, fy, fz, mx, my, mz]`` [N, N·m],
  linearly interpolated onto the joint samples by header stamp; joint samples outside the wrench's time span are
  dropped with a note. proprio takes it, as every ``f_ext``, as the wrench the environment exerts on the robot at the
  flange origin in the world frame; the message's ``frame_id`` is kept in ``meta.import.wrench_frame``.
* ``meta.tau_kind``: ``tau_kind`` when given, else the description's ``drive.tau_kind``, else ``link_sensor``.

The Recording then goes through the same checks as the CSV import (:func:`proprio.importer.import_recording`): a
joint's repeated stamp is averaged and counted (``meta.duplicate_stamps``, :func:`merge_duplicate_stamps`), a stamp
that runs backwards, NaN/inf, degrees, the joint count and limits and implausible τ/q̇ are errors
(:func:`proprio.recording.validate_recording`). Every failure is a :class:`proprio.importer.LogImportError` with one
line naming the bag, topic or joint.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from proprio.description import RobotDescription
from proprio.importer import TAU_KINDS, LogImportError
from proprio.recording import Recording, is_bag, validate_recording

__all__ = ["import_bag", "JOINT_STATE", "WRENCH_STAMPED"]

JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
_NS = 1_000_000_000


@dataclass
class _Stream:
    """The messages of one topic, flattened: per message its stamp [ns] and receive time [ns]; per (message, joint)
    entry the message index, the name, the values (NaN where the message leaves the field empty, as ROS allows) and
    ``given[field]``, whether the message filled that field."""
    stamp: np.ndarray
    received: np.ndarray
    msg: np.ndarray
    names: list[str]
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    given: dict[str, np.ndarray]
    frame: str = ""


def _fail(msg: str) -> LogImportError:
    return LogImportError(msg)


def _read_errors() -> tuple[type[BaseException], ...]:
    """What rosbags raises on a file it cannot read (a truncated chunk, a bad header, a foreign file)."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error

    return (AnyReaderError, Reader1Error, Reader2Error, OSError, EOFError, struct.error, ValueError, KeyError,
            IndexError, UnicodeDecodeError, AssertionError)


def _stamp_ns(msg: Any) -> int:
    st = msg.header.stamp
    return int(st.sec) * _NS + int(st.nanosec)


def _values(msg: Any, field: str, count: int, where: str) -> np.ndarray:
    """A JointState array field as [count] floats (NaN when the message leaves it empty, as ROS allows)."""
    arr = np.asarray(getattr(msg, field), dtype=float).reshape(-1)
    if arr.size == 0:
        return np.full(count, np.nan)
    if arr.size != count:
        raise _fail(f"{where}: '{field}' has {arr.size} values for {count} names")
    return arr


def _topics(reader: Any) -> dict[str, tuple[str, int]]:
    """``{topic: (message type, message count)}`` of an open reader."""
    out: dict[str, tuple[str, int]] = {}
    for c in reader.connections:
        kind, count = out.get(c.topic, (c.msgtype, 0))
        out[c.topic] = (kind, count + int(c.msgcount))
    return out


def _listing(topics: dict[str, tuple[str, int]]) -> str:
    return ", ".join(f"{t} ({k}, {n} messages)" for t, (k, n) in sorted(topics.items())) or "none"


def _pick(topics: dict[str, tuple[str, int]], topic: str | None, msgtype: str, flag: str, src: str) -> str:
    """The topic to read: ``topic`` checked for existence, type and messages, or the one topic of ``msgtype``."""
    if topic is None:
        found = sorted(t for t, (k, _) in topics.items() if k == msgtype)
        if not found:
            raise _fail(f"{src}: no {msgtype} topic; topics: {_listing(topics)}")
        if len(found) > 1:
            raise _fail(f"{src}: several {msgtype} topics ({', '.join(found)}); choose one with {flag}")
        topic = found[0]
    if topic not in topics:
        raise _fail(f"{src}: {flag} {topic}: no such topic; topics: {_listing(topics)}")
    kind, count = topics[topic]
    if kind != msgtype:
        raise _fail(f"{src}: {flag} {topic}: carries {kind}, not {msgtype}")
    if count == 0:
        raise _fail(f"{src}: {flag} {topic}: the topic has no messages")
    return topic


def _read_stream(reader: Any, topic: str, src: str, joint_state: bool) -> _Stream:
    """Deserialise every message of ``topic`` (one Python call per message is rosbags' API; everything after this is
    vectorised)."""
    conns = [c for c in reader.connections if c.topic == topic]
    stamps, received, msg_idx, names, pos, vel, eff = [], [], [], [], [], [], []
    given: dict[str, list[np.ndarray]] = {"position": [], "velocity": [], "effort": []}
    frame = ""
    for k, (conn, t_recv, raw) in enumerate(reader.messages(connections=conns)):
        m = reader.deserialize(raw, conn.msgtype)
        stamps.append(_stamp_ns(m))
        received.append(int(t_recv))
        where = f"{src}: {topic} message {k}"
        if joint_state:
            count = len(m.name)
            if count == 0:
                raise _fail(f"{where}: a JointState without joint names (proprio matches joints by name)")
            msg_idx.append(np.full(count, k))
            names.extend(str(n) for n in m.name)
            pos.append(_values(m, "position", count, where))
            vel.append(_values(m, "velocity", count, where))
            eff.append(_values(m, "effort", count, where))
            for field, parts in given.items():
                parts.append(np.full(count, len(getattr(m, field)) > 0))
        else:
            w = m.wrench
            pos.append(np.array([w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z], dtype=float))
            frame = frame or str(m.header.frame_id)
    return _Stream(stamp=np.asarray(stamps, dtype=np.int64), received=np.asarray(received, dtype=np.int64),
                   msg=np.concatenate(msg_idx) if joint_state else np.arange(len(stamps)), names=names,
                   position=np.concatenate(pos) if joint_state else np.stack(pos), velocity=np.concatenate(vel) if vel else np.empty(0),
                   effort=np.concatenate(eff) if eff else np.empty(0),
                   given={k: np.concatenate(v) for k, v in given.items() if v}, frame=frame)


def _time_base(s: _Stream, what: str, notes: list[str]) -> tuple[np.ndarray, str]:
    """Per-message time [ns] and its kind: the header stamps (``header``), or the receive times (``receive``) when
    the messages carry none (said so in ``notes``)."""
    if np.all(s.stamp == 0):
        notes.append(f"{what}: the messages carry no header stamp (0 s); the bag's receive times are the time base "
                     "(they hold the transport's jitter)")
        return s.received, "receive"
    if np.any(s.stamp == 0):
        raise _fail(f"{what}: {int(np.sum(s.stamp == 0))} of {s.stamp.size} messages have a zero header stamp and "
                    "the others not; the time base would mix two clocks")
    return s.stamp, "header"


def _merge_joints(s: _Stream, t_msg: np.ndarray, robot: RobotDescription, src: str, topic: str,
                  notes: list[str], meta: dict[str, Any]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Samples ``[N]`` ns and channels ``[N, n]`` in the description's joint order: entries matched by name, merged
    by stamp; a joint's repeated stamp averaged and counted; backwards stamps and missing joints are errors."""
    where = f"{src}: {topic}"
    order = {name: j for j, name in enumerate(robot.joint_names)}
    uniq_names, name_idx = np.unique(np.asarray(s.names, dtype=object).astype(str), return_inverse=True)
    col_of_name = np.array([order.get(str(nm), -1) for nm in uniq_names])
    extra = [str(nm) for nm, c in zip(uniq_names, col_of_name) if c < 0]
    missing = [nm for nm in robot.joint_names if nm not in set(uniq_names.tolist())]
    if missing:
        raise _fail(f"{where}: joint(s) {missing} of robot '{robot.name}' are in no message (the bag has "
                    f"{sorted(uniq_names.tolist())})")
    if extra:
        notes.append(f"{topic}: joint(s) {extra} are not in robot '{robot.name}' and were ignored")
    col = col_of_name[name_idx]
    keep = col >= 0
    col, msg = col[keep], s.msg[keep]
    t_entry = t_msg[msg]
    # a joint's stamps, in bag order, must not run backwards (the CSV import's rule: time that runs backwards is an error)
    by_joint = np.lexsort((msg, col))
    back = (np.diff(t_entry[by_joint]) < 0) & (np.diff(col[by_joint]) == 0)
    if back.any():
        i = by_joint[int(np.argmax(back)) + 1]
        raise _fail(f"{where}: the header stamp of joint {robot.joint_names[col[i]]!r} runs backwards at message "
                    f"{int(msg[i])} ({t_entry[i] / _NS:.9f} s after a later one)")
    stamps, row = np.unique(t_entry, return_inverse=True)
    shape = (stamps.size, robot.n)
    count = np.zeros(shape)
    np.add.at(count, (row, col), 1.0)
    chans: dict[str, np.ndarray] = {}
    for name, field in (("q", "position"), ("tau", "effort"), ("qd", "velocity")):
        v, ok = getattr(s, field)[keep], s.given[field][keep]
        bad = ok & ~np.isfinite(v)                       # a NaN/inf the robot logged (an empty field is no value)
        if bad.any():
            i = int(np.argmax(bad))
            raise _fail(f"{where}: message {int(msg[i])}: joint {robot.joint_names[col[i]]!r} {field} is {v[i]} "
                        f"({int(bad.sum())} non-finite value(s))")
        total, seen = np.zeros(shape), np.zeros(shape)
        np.add.at(total, (row[ok], col[ok]), v[ok])
        np.add.at(seen, (row[ok], col[ok]), 1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            chans[name] = np.where(seen > 0, total / np.maximum(seen, 1.0), np.nan)
        chans[name + "_seen"] = seen
    complete = np.all(count > 0, axis=1)
    if not complete.any():
        raise _fail(f"{where}: no stamp carries every joint of robot '{robot.name}' (messages with parts of the "
                    "joints are merged only when their header stamps are equal)")
    if not complete.all():
        notes.append(f"{topic}: {int((~complete).sum())} of {stamps.size} stamps miss some joint and were dropped")
    dup = count[complete] > 1
    if dup.any():
        meta["duplicate_stamps"] = {"stamps": int(dup.any(axis=1).sum()), "samples": int(count[complete][dup].sum()),
                                    "first_t": float((stamps[complete][np.argmax(dup.any(axis=1))] - stamps[0]) / _NS)}
    for name in ("q", "tau"):
        lacking = complete & np.any(chans[name + "_seen"] == 0, axis=1)
        if lacking.any():
            field = "position" if name == "q" else "effort"
            if lacking.all():
                raise _fail(f"{where}: the JointState messages carry no '{field}' (a Recording needs q and τ)")
            i = int(np.argmax(lacking))
            raise _fail(f"{where}: the sample at {(stamps[i] - stamps[0]) / _NS:.6f} s has no '{field}' for joint "
                        f"{robot.joint_names[int(np.argmax(chans[name + '_seen'][i] == 0))]!r}")
    has_qd = bool(np.all(chans["qd_seen"][complete] > 0))
    if not has_qd and np.any(chans["qd_seen"][complete] > 0):
        notes.append(f"{topic}: 'velocity' is missing at some samples; q̇ is left to the conditioning (from q)")
    out = {"q": chans["q"][complete], "tau": chans["tau"][complete]}
    if has_qd:
        out["qd"] = chans["qd"][complete]
    return stamps[complete], out


def import_bag(path: str | Path, robot: RobotDescription, topic: str | None = None,
               wrench_topic: str | None = None, tau_kind: str | None = None) -> Recording:
    """Read a ROS 1/ROS 2 bag (module docstring) into a validated Recording for ``robot``.

    ``topic``: the JointState topic (required when the bag has several); ``wrench_topic``: a WrenchStamped topic for
    ``f_ext``; ``tau_kind``: ``link_sensor`` | ``drive`` (default: the description's ``drive.tau_kind``, else
    ``link_sensor``). ``meta.import.notes`` holds what was ignored, dropped or assumed (the CLI prints them)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    src = str(path)
    if not path.exists():
        raise _fail(f"{src}: no such bag (a ROS 2 bag folder, a .mcap or .db3 file, or a ROS 1 .bag)")
    if not is_bag(path):
        raise _fail(f"{src}: not a bag — give a ROS 2 bag folder (with metadata.yaml), a .mcap or .db3 file, or a "
                    "ROS 1 .bag file")
    if tau_kind is not None and tau_kind not in TAU_KINDS:
        raise _fail(f"tau_kind: must be one of {list(TAU_KINDS)}, got {tau_kind!r}")
    kind = tau_kind or (robot.drive.tau_kind if robot.drive is not None else "link_sensor")
    notes: list[str] = []
    meta: dict[str, Any] = {}
    errors = _read_errors()
    try:
        # the ROS 2 default store for bags without embedded definitions (sqlite3 bags before Iron); ROS 1 bags and
        # MCAP files carry their own
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            topics = _topics(reader)
            js_topic = _pick(topics, topic, JOINT_STATE, "--topic", src)
            js = _read_stream(reader, js_topic, src, joint_state=True)
            wr = None
            if wrench_topic is not None:
                wrench_topic = _pick(topics, wrench_topic, WRENCH_STAMPED, "--wrench-topic", src)
                wr = _read_stream(reader, wrench_topic, src, joint_state=False)
    except LogImportError:
        raise
    except errors as exc:
        text = " ".join(str(exc).split()) or type(exc).__name__
        raise _fail(f"{src}: cannot read the bag ({text}); is it complete (a bag copied while being recorded is "
                    "truncated) and a ROS bag?") from None
    t_js, time_base = _time_base(js, js_topic, notes)
    stamps, chans = _merge_joints(js, t_js, robot, src, js_topic, notes, meta)
    f_ext = None
    if wr is not None:
        t_w, wrench_base = _time_base(wr, wrench_topic, notes)
        if wrench_base != time_base:
            raise _fail(f"{src}: {js_topic} is timed by {time_base} stamps, {wrench_topic} by {wrench_base} stamps; "
                        "the two clocks cannot be aligned")
        order = np.argsort(t_w, kind="stable")
        t_w, w = t_w[order], wr.position[order]
        if np.any(np.diff(t_w) <= 0):
            raise _fail(f"{src}: {wrench_topic}: repeated header stamps")
        inside = (stamps >= t_w[0]) & (stamps <= t_w[-1])
        if inside.sum() < 2:
            raise _fail(f"{src}: {wrench_topic} spans {(t_w[0] - stamps[0]) / _NS:.3f}..{(t_w[-1] - stamps[0]) / _NS:.3f}"
                        f" s of the joint states' 0..{(stamps[-1] - stamps[0]) / _NS:.3f} s: they do not overlap")
        if not inside.all():
            notes.append(f"{wrench_topic}: {int((~inside).sum())} joint samples outside the wrench's time span "
                         "were dropped")
            stamps, chans = stamps[inside], {k: v[inside] for k, v in chans.items()}
        x = (stamps - t_w[0]).astype(float)
        f_ext = np.stack([np.interp(x, (t_w - t_w[0]).astype(float), w[:, k]) for k in range(6)], axis=1)
        meta_wrench = {"wrench_topic": wrench_topic, "wrench_frame": wr.frame}
    else:
        meta_wrench = {}
    t = (stamps - stamps[0]).astype(float) / _NS
    meta.update({
        "source": f"proprio import of {path.name}", "robot": robot.name, "tau_kind": kind,
        "import": {"bag": path.name, "topic": js_topic, **meta_wrench, "joint_names": list(robot.joint_names),
                   "t0_ns": int(stamps[0]), "time_base": time_base, "notes": notes}})
    rec = Recording(t=t, q=chans["q"], tau=chans["tau"], qd=chans.get("qd"), f_ext=f_ext, meta=meta)
    rec = validate_recording(rec, robot, source=f"{src}: {js_topic}")
    rec.meta["rate_hz"] = rec.rate_hz
    return rec
