"""Real signals end to end: a twin Recording holds only what a robot logs (jittered stamps, encoder q, τ_J; no q̇, q̈),
and every command that reads a Recording runs on it through the one conditioning path; on the real LWR 4+ files the
recorded q̇/q̈ channels change nothing."""
from __future__ import annotations

import json

import numpy as np
import pytest

from proprio.cli import main
from proprio.recording import load_recording


@pytest.fixture(scope="module")
def robot_log(tmp_path_factory, full):
    """The calibrated twin on RFMA, logged like a robot: q and τ_J only, jittered stamps, lost samples (at 200 Hz to
    keep the test short; the 1 kHz log of the same logger is benchmarks/bench_robot_log.py's). 8 s of 1 scaffold;
    22 s of 3 under --full."""
    d = tmp_path_factory.mktemp("robot_log")
    scaffolds, seconds = ("3", "22") if full else ("1", "8")
    assert main(["trajectory", "rfma", "--scaffolds", scaffolds, "--seed", "2", "--out", str(d / "traj.npz")]) == 0
    assert main(["simulate", "--trajectory", str(d / "traj.npz"), "--seconds", seconds, "--log-rate", "200",
                 "--quiet", "--out", str(d / "rec.npz")]) == 0
    return d


def test_a_twin_recording_has_only_measured_channels(robot_log):
    with np.load(robot_log / "rec.npz", allow_pickle=False) as z:
        keys = set(z.files)
    assert {"t", "q", "tau"} <= keys and not keys & {"qd", "qdd"}
    assert {"truth__qd", "truth__qdd", "truth__q_true", "truth__t_true"} <= keys
    rec = load_recording(robot_log / "rec.npz")
    steps = np.diff(rec.t)
    assert np.ptp(steps) > 2e-4 and rec.meta["channels"] == ["q", "tau"]        # jittered stamps
    assert abs(np.median(steps) - 5e-3) < 1e-4


def test_every_command_runs_on_a_robot_log(robot_log, capsys):
    rec, d = str(robot_log / "rec.npz"), robot_log
    assert main(["inspect", rec]) == 0
    assert "conditioning:" in capsys.readouterr().out
    assert main(["identify", "--robot", "iiwa14_nominal", "--train", rec, "--validate", rec, "--method", "ols",
                 "--out", str(d / "model.npz")]) == 0
    assert "conditioning:" in capsys.readouterr().out
    assert main(["estimate", "--recording", rec, "--out", str(d / "est")]) == 0
    assert main(["view", rec, "--html", str(d / "view.html"), "--end", "3"]) == 0
    # two candidates keep it short (the whole library on one 22 s log of the calibrated twin takes ≈ 7 min)
    assert main(["diagnose", "--model", "iiwa14_identified", "--train", rec, "--candidates", "sensor_offset",
                 "lost_motion", "--holdout-fraction", "0.5", "--out", str(d / "diag")]) == 0   # 8 s: hold out 4
    assert "conditioning:" in (d / "diag" / "report.md").read_text()
    cfg = d / "tiny.yaml"
    cfg.write_text("model: {arch: lstm2_fcl, hybrid: true, use_r: true, lstm_hidden: 8}\n"
                   "data: {decimate: 2, window: 20}\ntrain: {max_epochs: 2, batch_size: 4}\n")
    assert main(["train", "--config", str(cfg), "--data", rec, "--out", str(d / "m.pt")]) == 0
    assert main(["evaluate", "--model", str(d / "m.pt"), "--data", rec]) == 0
    assert main(["simulate", "--trajectory", rec, "--seconds", "2", "--quiet", "--out", str(d / "replay.npz")]) == 0
    assert load_recording(d / "replay.npz").duration == pytest.approx(2.0, abs=0.05)
    capsys.readouterr()


def _without(rec, *channels):
    return rec.replace(**{c: None for c in channels})


def test_lwr_results_do_not_depend_on_the_recorded_derivatives(lwr_dir):
    """identify's validation error and the diagnosis' data path: identical with the files' q̇, q̈, without q̈, and
    without both (q̇, q̈ always come from q by the conditioning path)."""
    from proprio.description import load_robot
    from proprio.identification.recordings import identify_recordings
    from proprio.recording import load_lwr4

    robot = load_robot(lwr_dir)
    recs = {i: load_lwr4(lwr_dir, i) for i in (1, 2, 3)}
    assert recs[1].qd is not None and recs[1].qdd is not None
    tables = []
    for drop in ((), ("qdd",), ("qd", "qdd")):
        train = [_without(recs[i], *drop) for i in (2, 3)]
        _, table = identify_recordings(train, [_without(recs[1], *drop)], robot, trim_s=2.5)
        tables.append(table)
    assert tables[0] == tables[1] == tables[2]
    assert "validation" in tables[0]


@pytest.mark.slow
def test_lwr_diagnosis_verdict_does_not_depend_on_the_recorded_derivatives(lwr_dir, tmp_path):
    """The whole diagnosis on the real files with and without their q̇, q̈ channels (make test checks the conditioning
    path on the same files through identify, above; two linear candidates alone still cost ≈ 80 s of CPU)."""
    files = [str(lwr_dir / f"measurements_{i}.npz") for i in (1, 2, 3)]
    from proprio.recording import load_lwr4, save_recording
    stripped = []
    for i in (1, 2, 3):
        rec = _without(load_lwr4(lwr_dir, i), "qd", "qdd")
        stripped.append(str(save_recording(rec, tmp_path / f"m{i}_q_tau.npz")))
    out = {}
    for name, recs in (("with", files), ("without", stripped)):
        assert main(["diagnose", "--model", str(lwr_dir), "--train", recs[1], recs[2], "--holdout", recs[0],
                     "--out", str(tmp_path / name)]) == 0
        out[name] = json.loads((tmp_path / name / "diagnosis.json").read_text())
    steps = {k: [s["name"] for s in v["steps"]] for k, v in out.items()}
    assert steps["with"] == steps["without"] and steps["with"]               # the same effects, in the same order
    assert out["with"]["verdict"] == out["without"]["verdict"]
    np.testing.assert_allclose(out["with"]["steps"][-1]["rmse_after"], out["without"]["steps"][-1]["rmse_after"],
                               rtol=1e-9)
