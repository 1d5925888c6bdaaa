"""The Recording format: bit-exact save/load round trips (hypothesis), precise errors for every kind of corruption,
CSV import, atomic writes, and the real LWR 4+ files."""
from __future__ import annotations

import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from proprio.description import load_robot
from proprio.recording import (Recording, RecordingError, is_lwr4_file, load_lwr4, load_recording,
                               recording_from_csv, save_recording, validate_recording)

F64 = np.float64
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
angles = st.floats(-2 * np.pi, 2 * np.pi, allow_nan=False, width=64)
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | finite | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=10)


@st.composite
def recordings(draw) -> Recording:
    n_s = draw(st.integers(2, 30))
    n = draw(st.integers(1, 8))
    dt = draw(arrays(F64, n_s - 1, elements=st.floats(1e-3, 10.0)))
    t = draw(st.floats(-1e3, 1e3)) + np.concatenate([[0.0], np.cumsum(dt)])
    joint = lambda elements=finite: arrays(F64, (n_s, n), elements=elements)  # noqa: E731
    maybe = lambda strategy: st.none() | strategy  # noqa: E731
    truth = draw(st.dictionaries(
        st.from_regex(r"[a-z][a-z0-9_]{0,12}", fullmatch=True),
        st.integers(0, 2).flatmap(lambda extra: arrays(F64, (n_s,) + (3,) * extra, elements=finite)), max_size=3))
    return Recording(t=t, q=draw(joint(angles)), tau=draw(joint()), qd=draw(maybe(joint())), qdd=draw(maybe(joint())),
                     f_ext=draw(maybe(arrays(F64, (n_s, 6), elements=finite))), truth=truth,
                     meta=draw(st.dictionaries(st.text(max_size=10), json_values, max_size=5)))


def assert_bit_exact(a: np.ndarray | None, b: np.ndarray | None) -> None:
    if a is None or b is None:
        assert a is None and b is None
        return
    assert a.dtype == b.dtype == F64 and a.shape == b.shape
    assert a.tobytes() == b.tobytes()  # bit-exact: distinguishes -0.0 from 0.0, keeps every subnormal


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rec=recordings())
def test_save_load_round_trip_is_bit_exact(rec):
    with tempfile.TemporaryDirectory() as d:
        path = save_recording(rec, Path(d) / "rec.npz")
        back = load_recording(path)
    for name in ("t", "q", "tau", "qd", "qdd", "f_ext"):
        assert_bit_exact(getattr(rec, name), getattr(back, name))
    assert set(back.truth) == set(rec.truth)
    for k, v in rec.truth.items():
        assert_bit_exact(v, back.truth[k])
    assert back.meta == rec.meta
    assert json.dumps(back.meta, sort_keys=True) == json.dumps(rec.meta, sort_keys=True)


# ---- corruption: every problem gets a one-line RecordingError naming it --------------------------------------------

def good(n_s: int = 50, n: int = 7) -> Recording:
    rng = np.random.default_rng(0)
    t = np.arange(n_s) * 0.005
    q = 0.5 * np.sin(np.outer(t, np.arange(1, n + 1)))
    return Recording(t=t, q=q, tau=rng.normal(size=(n_s, n)), qd=np.gradient(q, t, axis=0),
                     truth={"tau_rbd": rng.normal(size=(n_s, n))}, meta={"robot": "iiwa14_identified", "seed": 0})


def write_npz(path: Path, **arrays_) -> Path:
    np.savez(path, **arrays_)
    return path


def raw(rec: Recording) -> dict[str, np.ndarray]:
    out = {"t": rec.t, "q": rec.q, "tau": rec.tau, "meta": np.array(json.dumps(rec.meta))}
    if rec.qd is not None:
        out["qd"] = rec.qd
    return out


def expect_error(path: Path, *fragments: str, robot=None) -> str:
    with pytest.raises(RecordingError) as info:
        load_recording(path, robot=robot)
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert str(path) in msg
    for f in fragments:
        assert f in msg, f"{f!r} not in {msg!r}"
    return msg


def test_truncated_file(tmp_path):
    data = save_recording(good(), tmp_path / "ok.npz").read_bytes()
    for cut in (10, len(data) // 3, len(data) - 5):
        p = tmp_path / f"cut{cut}.npz"
        p.write_bytes(data[:cut])
        expect_error(p, "truncated or corrupted")


def test_corrupted_bytes(tmp_path):
    """A byte flipped inside any member's compressed data (zlib or the zip CRC catches it) is a one-line
    RecordingError naming the file."""
    ok = save_recording(good(), tmp_path / "ok.npz")
    data = ok.read_bytes()
    load_recording(ok)
    with zipfile.ZipFile(ok) as z:
        members = z.infolist()
    assert len(members) >= 4
    rng = np.random.default_rng(1)
    for info in members:
        head = info.header_offset
        name_len, extra_len = (int.from_bytes(data[head + k:head + k + 2], "little") for k in (26, 28))
        start = head + 30 + name_len + extra_len                      # the member's deflate stream
        for pos in (start, start + int(rng.integers(1, int(0.9 * info.compress_size)))):
            b = bytearray(data)
            b[pos] ^= 0xFF
            p = tmp_path / f"flip_{info.filename}_{pos}.npz"
            p.write_bytes(bytes(b))
            expect_error(p, "truncated or corrupted")


def test_not_an_npz(tmp_path):
    p = tmp_path / "text.npz"
    p.write_text("t,q1\n0,0\n")
    expect_error(p, "not a readable .npz")


def test_missing_file(tmp_path):
    expect_error(tmp_path / "nope.npz", "no such file")


def test_nan_and_inf(tmp_path):
    rec = good()
    q = rec.q.copy()
    q[17, 3] = np.nan
    expect_error(write_npz(tmp_path / "nan.npz", **{**raw(rec), "q": q}), "'q'", "NaN", "sample 17")
    tau = rec.tau.copy()
    tau[5, 0] = -np.inf
    expect_error(write_npz(tmp_path / "inf.npz", **{**raw(rec), "tau": tau}), "'tau'", "inf", "sample 5")
    qd = rec.qd.copy()
    qd[9, 1] = np.nan
    expect_error(write_npz(tmp_path / "nan_qd.npz", **{**raw(rec), "qd": qd}), "'qd'", "NaN")
    t = rec.t.copy()
    t[2] = np.nan
    expect_error(write_npz(tmp_path / "nan_t.npz", **{**raw(rec), "t": t}), "'t'", "NaN")


def test_shuffled_and_repeated_time(tmp_path):
    rec = good()
    perm = np.random.default_rng(2).permutation(rec.n_samples)
    shuffled = {k: (v[perm] if k != "meta" else v) for k, v in raw(rec).items()}
    expect_error(write_npz(tmp_path / "shuffled.npz", **shuffled), "'t'", "not strictly increasing")
    t = rec.t.copy()
    t[10] = t[9]
    expect_error(write_npz(tmp_path / "repeat.npz", **{**raw(rec), "t": t}), "not strictly increasing", "t[10]")


def test_degrees_rejected(tmp_path):
    rec = good()
    expect_error(write_npz(tmp_path / "deg.npz", **{**raw(rec), "q": np.degrees(rec.q)}), "'q'", "radians")


def test_wrong_joint_count_for_robot(tmp_path, iiwa):
    rec = good(n=6)
    p = save_recording(rec, tmp_path / "six.npz")
    assert load_recording(p).n_joints == 6  # valid on its own
    expect_error(p, "6 joints", "iiwa14_identified", "7", robot=iiwa)


def test_outside_joint_limits(tmp_path, iiwa):
    rec = good()
    q = rec.q.copy()
    q[20, 1] = np.radians(125)  # joint 2 limit is ±120°
    p = save_recording(rec.replace(q=q), tmp_path / "limits.npz")
    expect_error(p, "joint 1", "iiwa_joint_2", "outside the limits", "sample 20", robot=iiwa)


def test_missing_key(tmp_path):
    arrays_ = raw(good())
    del arrays_["tau"]
    expect_error(write_npz(tmp_path / "notau.npz", **arrays_), "missing key", "tau")


def test_shape_mismatches(tmp_path):
    rec = good()
    expect_error(write_npz(tmp_path / "short.npz", **{**raw(rec), "tau": rec.tau[:-1]}), "'tau'", "shape")
    expect_error(write_npz(tmp_path / "fext.npz", **{**raw(rec), "f_ext": np.zeros((rec.n_samples, 3))}),
                 "'f_ext'", "shape", "6")
    expect_error(write_npz(tmp_path / "truth.npz", **{**raw(rec), "truth__tau_rbd": np.zeros((3, 7))}),
                 "truth channel 'tau_rbd'")
    expect_error(write_npz(tmp_path / "t2d.npz", **{**raw(rec), "t": rec.t[:, None]}), "'t'", "shape")
    one = good(n_s=2).slice(0, 1)
    expect_error(write_npz(tmp_path / "one.npz", **raw(one)), "at least 2")


def test_bad_meta(tmp_path):
    expect_error(write_npz(tmp_path / "meta.npz", **{**raw(good()), "meta": np.array("{not json")}), "'meta'",
                 "JSON")
    with pytest.raises(RecordingError, match="'meta' is not strict JSON"):
        save_recording(good().replace(meta={"x": object()}), tmp_path / "m.npz")
    with pytest.raises(RecordingError, match="'meta' is not strict JSON"):
        save_recording(good().replace(meta={"x": float("nan")}), tmp_path / "m.npz")
    with pytest.raises(RecordingError, match="'meta' keys must be strings"):
        save_recording(good().replace(meta={1: "a"}), tmp_path / "m.npz")
    # tuples are normalised to lists, so what is saved is what comes back
    rec = validate_recording(good().replace(meta={"com": (0.0, 0.1, 0.2)}))
    save_recording(rec, tmp_path / "m.npz")
    assert load_recording(tmp_path / "m.npz").meta == rec.meta == {"com": [0.0, 0.1, 0.2]}


def test_object_arrays_are_not_unpickled(tmp_path):
    p = tmp_path / "pickle.npz"
    np.savez(p, **{**raw(good()), "tau": np.array([object()] * 50, dtype=object)})
    msg = expect_error(p)
    assert "allow_pickle" in msg


def test_save_rejects_invalid_and_wrong_suffix(tmp_path):
    rec = good()
    with pytest.raises(RecordingError, match="must end in .npz"):
        save_recording(rec, tmp_path / "rec.csv")
    q = rec.q.copy()
    q[0, 0] = np.inf
    with pytest.raises(RecordingError, match="'q' contains 1 non-finite"):
        save_recording(rec.replace(q=q), tmp_path / "bad.npz")
    assert not list(tmp_path.iterdir())


# ---- atomic writes ---------------------------------------------------------------------------------------------------

def test_interrupted_save_leaves_no_file(tmp_path, monkeypatch):
    target = tmp_path / "rec.npz"

    def half_then_interrupt(path, **arrays_):
        Path(path).write_bytes(b"PK\x03\x04 half a zip")
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", half_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        save_recording(good(), target)
    assert list(tmp_path.iterdir()) == []  # neither the target nor a temporary file


def test_interrupted_save_keeps_previous_file(tmp_path, monkeypatch):
    target = save_recording(good(), tmp_path / "rec.npz")
    before = target.read_bytes()

    def fail(path, **arrays_):
        Path(path).write_bytes(b"garbage")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", fail)
    with pytest.raises(OSError, match="disk full"):
        save_recording(good(n_s=10), target)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["rec.npz"]


# ---- CSV import ------------------------------------------------------------------------------------------------------

def write_csv(path: Path, rec: Recording, scale: float = 1.0, with_qd: bool = True, drop: str | None = None) -> Path:
    n = rec.n_joints
    cols = {"t": rec.t[:, None]}
    cols.update({f"q{i + 1}": rec.q[:, i:i + 1] * scale for i in range(n)})
    cols.update({f"tau{i + 1}": rec.tau[:, i:i + 1] for i in range(n)})
    if with_qd:
        cols.update({f"qd{i + 1}": rec.qd[:, i:i + 1] * scale for i in range(n)})
    cols.pop(drop, None)
    np.savetxt(path, np.hstack(list(cols.values())), delimiter=",", header=",".join(cols), comments="")
    return path


def test_csv_import_radians_and_degrees(tmp_path):
    rec = good()
    a = recording_from_csv(write_csv(tmp_path / "rad.csv", rec), n_joints=7)
    b = recording_from_csv(write_csv(tmp_path / "deg.csv", rec, scale=180 / np.pi), n_joints=7, angle_unit="deg")
    for r in (a, b):
        np.testing.assert_allclose(r.q, rec.q, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(r.qd, rec.qd, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(r.tau, rec.tau, rtol=1e-15)
        assert r.qdd is None and r.f_ext is None
    assert b.meta["source"] == "csv:deg.csv"


def test_csv_degrees_read_as_radians_is_an_error(tmp_path):
    p = write_csv(tmp_path / "deg.csv", good(), scale=180 / np.pi)
    with pytest.raises(RecordingError, match="radians"):
        recording_from_csv(p, n_joints=7)


def test_csv_missing_and_partial_columns(tmp_path):
    rec = good()
    with pytest.raises(RecordingError, match=r"missing column\(s\) \['tau4'\]"):
        recording_from_csv(write_csv(tmp_path / "a.csv", rec, drop="tau4"), n_joints=7)
    with pytest.raises(RecordingError, match=r"missing column\(s\) \['qd2'\]"):
        recording_from_csv(write_csv(tmp_path / "b.csv", rec, drop="qd2"), n_joints=7)
    with pytest.raises(RecordingError, match="missing column 't'"):
        recording_from_csv(write_csv(tmp_path / "c.csv", rec, drop="t"), n_joints=7)
    with pytest.raises(RecordingError, match="angle_unit"):
        recording_from_csv(tmp_path / "a.csv", n_joints=7, angle_unit="grad")


def test_csv_wrench_columns(tmp_path):
    rec = good(n_s=20, n=2)
    p = tmp_path / "w.csv"
    f = np.arange(120.0).reshape(20, 6)
    table = np.hstack([rec.t[:, None], rec.q, rec.tau, f])
    np.savetxt(p, table, delimiter=",", header="t,q1,q2,tau1,tau2,fx,fy,fz,mx,my,mz", comments="")
    r = recording_from_csv(p, n_joints=2)
    np.testing.assert_array_equal(r.f_ext, f)


# ---- the real LWR 4+ files -------------------------------------------------------------------------------------------

def test_lwr4_files_load_and_validate(lwr_dir):
    robot = load_robot(lwr_dir)
    for index in (1, 2, 3):
        path = lwr_dir / f"measurements_{index}.npz"
        assert is_lwr4_file(path)
        rec = load_lwr4(lwr_dir, index)
        with np.load(path) as z:
            np.testing.assert_array_equal(rec.q, z["positions"])
            np.testing.assert_array_equal(rec.tau, z["torques"])
            np.testing.assert_array_equal(rec.qd, z["velocities"])
            np.testing.assert_array_equal(rec.t, z["times"] - z["times"][0])
        assert rec.n_samples == 5027 and rec.n_joints == 7
        assert rec.t[0] == 0.0 and rec.duration == pytest.approx(25.13, abs=0.01)
        assert rec.rate_hz == pytest.approx(200.0, rel=1e-3) and rec.meta["robot"] == "kuka_lwr4plus"
        validate_recording(rec, robot)
        same = load_recording(path, robot)
        np.testing.assert_array_equal(same.tau, rec.tau)


def test_lwr4_corrupted_copies(lwr_dir, tmp_path):
    with np.load(lwr_dir / "measurements_1.npz") as z:
        data = {k: z[k] for k in z.files}
    expect_error(write_npz(tmp_path / "deg.npz", **{**data, "positions": np.degrees(data["positions"])}), "radians")
    times = data["times"].copy()
    times[100], times[101] = times[101], times[100]
    expect_error(write_npz(tmp_path / "swap.npz", **{**data, "times": times}), "not strictly increasing")
    assert not is_lwr4_file(tmp_path / "missing.npz")
    (tmp_path / "m.npz").write_bytes((lwr_dir / "measurements_1.npz").read_bytes()[:50000])
    expect_error(tmp_path / "m.npz", "truncated")
    with pytest.raises(RecordingError, match="no such file"):
        load_lwr4(tmp_path, 9)


def test_slice_copies():
    rec = good()
    part = rec.slice(10, 20)
    assert part.n_samples == 10 and part.truth["tau_rbd"].shape == (10, 7)
    part.q[0, 0] = 99.0
    assert rec.q[10, 0] != 99.0


def test_npz_members_are_plain_arrays(tmp_path):
    path = save_recording(good(), tmp_path / "r.npz")
    with zipfile.ZipFile(path) as z:
        assert sorted(z.namelist()) == sorted(["t.npy", "q.npy", "tau.npy", "qd.npy", "truth__tau_rbd.npy",
                                               "meta.npy"])


def test_zero_joints_rejected():
    with pytest.raises(RecordingError, match="'q' has no joint columns"):
        validate_recording(Recording(t=np.arange(3.0), q=np.zeros((3, 0)), tau=np.zeros((3, 0))))


def test_saved_file_has_normal_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        path = save_recording(good(), tmp_path / "perm.npz")
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644  # not mkstemp's private 0600
