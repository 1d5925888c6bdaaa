"""The ``proprio`` CLI: --help everywhere, ``inspect`` numbers and errors, ``payload-experiment`` (``demo``: test_demo.py)."""
from __future__ import annotations

import argparse
import re
import subprocess
import sys

import numpy as np
import pytest

from proprio.cli import build_parser, main
from proprio.inspection import reversal_counts, summarize_recording
from proprio.recording import Recording, save_recording


def subcommands() -> list[str]:
    parser = build_parser()
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sorted(actions[0].choices) if actions else []


def test_top_level_help_via_entry_point():
    out = subprocess.run([sys.executable, "-m", "proprio", "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for cmd in subcommands():
        assert cmd in out.stdout


def test_expected_commands_present():
    assert {"inspect", "demo"} <= set(subcommands())


@pytest.mark.parametrize("cmd", subcommands())
def test_every_subcommand_has_help(cmd, capsys):
    with pytest.raises(SystemExit) as info:
        main([cmd, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert f"proprio {cmd}" in out and len(out.splitlines()) > 3


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


# ---- reversal counting -----------------------------------------------------------------------------------------------

def reference_reversals(qd: np.ndarray, deadband: float) -> np.ndarray:
    """Per-sample loop (the definition), to check the vectorised version."""
    counts = np.zeros(qd.shape[1], dtype=int)
    for j in range(qd.shape[1]):
        state = 0
        for v in qd[:, j]:
            new = 1 if v > deadband else -1 if v < -deadband else state
            if state and new != state:
                counts[j] += 1
            state = new
    return counts


def test_reversals_ignore_noise_inside_deadband():
    t = np.linspace(0, 10, 5001)
    qd = np.cos(2 * np.pi * 0.5 * t)[:, None] * [1.0, 0.0]          # 10 zero crossings on joint 0, none on joint 1
    noisy = qd + np.random.default_rng(0).uniform(-0.009, 0.009, qd.shape)
    np.testing.assert_array_equal(reversal_counts(noisy, deadband=0.01), [10, 0])
    assert reversal_counts(noisy, deadband=0.0)[1] > 100  # without a deadband noise chatters


def test_reversals_match_reference_definition():
    rng = np.random.default_rng(1)
    qd = np.cumsum(rng.normal(size=(3000, 4)), axis=0) * 0.01 + rng.normal(size=(3000, 4)) * 0.02
    for db in (0.0, 0.01, 0.05):
        np.testing.assert_array_equal(reversal_counts(qd, db), reference_reversals(qd, db))


def test_summary_uses_central_differences_without_qd():
    t = np.linspace(0, 2, 401)
    q = np.stack([np.sin(np.pi * t), 0.1 * t], axis=1)
    s = summarize_recording(Recording(t=t, q=q, tau=np.ones_like(q)))
    assert s["qd_source"].startswith("central differences")
    np.testing.assert_allclose(s["qd_abs_max_rad_s"], [np.pi, 0.1], rtol=1e-3)
    np.testing.assert_array_equal(s["reversals"], [2, 0])
    np.testing.assert_allclose(s["tau_rms_nm"], [1.0, 1.0])


# ---- proprio inspect on the real LWR 4+ file -------------------------------------------------------------------------

def parse_table(text: str) -> dict[str, list[float]]:
    rows = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 8 and re.fullmatch(r"lwr_\d_joint|j\d|iiwa_joint_\d", parts[0]):
            rows[parts[0]] = [float(x) for x in parts[1:]]
    return rows


def test_inspect_lwr_file_prints_correct_summary(lwr_dir, capsys, tmp_path):
    path = lwr_dir / "measurements_1.npz"
    png = tmp_path / "plots" / "m1.png"
    assert main(["inspect", str(path), "--robot", str(lwr_dir), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    with np.load(path) as z:
        t, q, qd, tau = z["times"], z["positions"], z["velocities"], z["torques"]
    duration = t[-1] - t[0]
    assert f"duration {duration:.3f} s" in out
    assert f"rate {1 / np.median(np.diff(t)):.2f} Hz" in out
    assert f"(dt {1e3 * np.diff(t).min():.3g}–{1e3 * np.diff(t).max():.3g} ms)" in out
    assert "samples 5027" in out and "joints 7" in out
    rows = parse_table(out)
    assert list(rows) == [f"lwr_{i}_joint" for i in range(7)]
    table = np.array(list(rows.values()))
    np.testing.assert_allclose(table[:, 0], q.min(0), atol=5e-4)
    np.testing.assert_allclose(table[:, 1], q.max(0), atol=5e-4)
    np.testing.assert_allclose(table[:, 2], np.degrees(q.min(0)), atol=0.05)
    np.testing.assert_allclose(table[:, 3], np.degrees(q.max(0)), atol=0.05)
    np.testing.assert_allclose(table[:, 4], np.abs(qd).max(0), atol=5e-4)
    np.testing.assert_allclose(table[:, 5], np.sqrt((tau ** 2).mean(0)), atol=5e-4)
    np.testing.assert_allclose(table[:, 6], reference_reversals(qd, 0.01) / duration, atol=5e-4)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"plot: {png}" in out
    quality = out[out.index("data quality"):out.index("plot: ")]   # findings under the table, before the plot
    assert "WARNING  tau_filtered   τ all 7 joints" in quality and "WARNING  qd_lag" in quality
    assert "  conditioning: 200 Hz uniform grid" in quality


def test_inspect_without_robot_names_joints_generically(lwr_dir, capsys):
    assert main(["inspect", str(lwr_dir / "measurements_2.npz")]) == 0
    assert list(parse_table(capsys.readouterr().out)) == [f"j{i}" for i in range(1, 8)]


# ---- corrupted input: exit 2 with one line naming the problem ----------------------------------------------------

def good_recording(n: int = 7) -> Recording:
    t = np.arange(200) * 0.01
    q = 0.3 * np.sin(np.outer(t, np.arange(1, n + 1)))
    return Recording(t=t, q=q, tau=np.cos(q), meta={"robot": "test"})


def expect_exit_2(argv: list[str], capsys, *fragments: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert err.startswith("proprio: error: ")
    for f in fragments:
        assert f in err, f"{f!r} not in {err!r}"


def test_inspect_corrupted_files_exit_2(tmp_path, capsys):
    rec = good_recording()
    ok = save_recording(rec, tmp_path / "ok.npz")
    assert main(["inspect", str(ok)]) == 0
    capsys.readouterr()

    trunc = tmp_path / "truncated.npz"
    trunc.write_bytes(ok.read_bytes()[:300])
    expect_exit_2(["inspect", str(trunc)], capsys, "truncated.npz", "truncated or corrupted")

    q = rec.q.copy()
    q[50, 2] = np.nan
    np.savez(tmp_path / "nan.npz", t=rec.t, q=q, tau=rec.tau)
    expect_exit_2(["inspect", str(tmp_path / "nan.npz")], capsys, "'q'", "NaN", "sample 50")

    perm = np.random.default_rng(0).permutation(len(rec.t))
    np.savez(tmp_path / "shuffled.npz", t=rec.t[perm], q=rec.q[perm], tau=rec.tau[perm])
    expect_exit_2(["inspect", str(tmp_path / "shuffled.npz")], capsys, "'t'", "not strictly increasing")

    np.savez(tmp_path / "degrees.npz", t=rec.t, q=np.degrees(rec.q) * 10, tau=rec.tau)
    expect_exit_2(["inspect", str(tmp_path / "degrees.npz")], capsys, "'q'", "radians")

    np.savez(tmp_path / "nokey.npz", t=rec.t, q=rec.q)
    expect_exit_2(["inspect", str(tmp_path / "nokey.npz")], capsys, "missing key", "tau")

    expect_exit_2(["inspect", str(tmp_path / "absent.npz")], capsys, "no such file")


def test_inspect_robot_mismatch_exit_2(tmp_path, capsys):
    p = save_recording(good_recording(n=6), tmp_path / "six.npz")
    expect_exit_2(["inspect", str(p), "--robot", "iiwa14_nominal"], capsys, "6 joints", "iiwa14_nominal")
    expect_exit_2(["inspect", str(p), "--robot", "no_such_robot"], capsys, "unknown robot 'no_such_robot'")
    expect_exit_2(["inspect", str(p), "--deadband", "-1"], capsys, "deadband")


def test_inspect_degrees_lwr_copy_exit_2(lwr_dir, tmp_path, capsys):
    with np.load(lwr_dir / "measurements_1.npz") as z:
        data = {k: z[k] for k in z.files}
    data["positions"] = np.degrees(data["positions"])
    np.savez(tmp_path / "lwr_deg.npz", **data)
    expect_exit_2(["inspect", str(tmp_path / "lwr_deg.npz")], capsys, "lwr_deg.npz", "radians")


# ---- proprio payload-experiment ------------------------------------------------------------------------------

def assert_tared_payload_seen(table: str) -> None:
    """Table 5.4's taring rows: every observer sees the 1 kg payload's weight along z within 0.5 N (of 9.8 N)."""
    seen = table[table.index("Payload seen after taring"):]
    rows = re.findall(r"^(\w[\w -]*?)\s+1000g\s+\[([^\]]+)\]\s+\(\[([^\]]+)\]\)", seen, flags=re.M)
    assert len(rows) == 4, seen
    for observer, est, true in rows:
        est, true = np.array(est.split(), float), np.array(true.split(), float)
        assert true[2] == pytest.approx(-9.81, abs=0.1) and abs(est[2] - true[2]) < 0.5, (observer, est, true)


def test_payload_experiment_command(tmp_path, capsys):
    """``proprio payload-experiment`` on 6 s of the calibrated twin with the twin's own rigid-body model."""
    assert main(["payload-experiment", "--seconds", "6", "--masses", "0", "1", "--out", str(tmp_path)]) == 0
    assert "Table 5.4" in capsys.readouterr().out
    assert_tared_payload_seen((tmp_path / "table.txt").read_text())


def test_inspect_csv_with_duplicate_stamps(tmp_path, capsys):
    rec = good_recording(n=2)
    table = np.hstack([rec.t[:, None], rec.q, rec.tau])
    table = np.insert(table, 40, table[39], axis=0)                  # one stamp logged twice
    np.savetxt(tmp_path / "dup.csv", table, delimiter=",", header="t,q1,q2,tau1,tau2", comments="")
    assert main(["inspect", str(tmp_path / "dup.csv")]) == 0
    out = capsys.readouterr().out
    assert "samples 200" in out
    assert "WARNING  duplicates     t: 1 duplicated time stamp(s) (2 samples)" in out


def test_inspect_csv_in_degrees(tmp_path, capsys):
    rec = good_recording(n=3)
    header = "t,q1,q2,q3,tau1,tau2,tau3"
    table = np.hstack([rec.t[:, None], np.degrees(rec.q), rec.tau])
    np.savetxt(tmp_path / "deg.csv", table, delimiter=",", header=header, comments="")
    assert main(["inspect", str(tmp_path / "deg.csv"), "--angle-unit", "deg"]) == 0
    rows = np.array(list(parse_table(capsys.readouterr().out).values()))
    np.testing.assert_allclose(rows[:, 0], rec.q.min(0), atol=5e-4)
    np.testing.assert_allclose(rows[:, 3], np.degrees(rec.q.max(0)), atol=0.05)
    expect_exit_2(["inspect", str(tmp_path / "deg.csv")], capsys, "deg.csv", "radians")  # degrees read as rad
    (tmp_path / "noq.csv").write_text("t,a,b\n0,1,2\n1,1,2\n")
    expect_exit_2(["inspect", str(tmp_path / "noq.csv")], capsys, "no 'q1'")


def test_multiline_parser_errors_become_one_line(tmp_path, capsys):
    p = save_recording(good_recording(), tmp_path / "ok.npz")
    bad = tmp_path / "broken.yaml"
    bad.write_text("name: x\njoints: [\n  - {name: a\n")
    expect_exit_2(["inspect", str(p), "--robot", str(bad)], capsys, "broken.yaml", "invalid YAML")
