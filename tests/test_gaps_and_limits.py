"""Hostile inputs (issue 26): no stage invents data inside a gap of the log, implausible values are refused at the
boundary naming the field, and ``dataset`` shuts down cleanly (no orphan worker, no temporary file) and refuses a
second writer into its directory."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from proprio.cli import main
from proprio.description import DescriptionError, load_robot
from proprio.dynamics import inverse_dynamics
from proprio.io import DirectoryLocked, locked_dir
from proprio.kinematics import flange_jacobian
from proprio.recording import Recording, load_recording, save_recording

RATE, DURATION = 500.0, 8.0
HOLE = (3.0, 5.0)                             # [s]: the log has no sample in [3, 5)
FORCE = np.array([15.0, -5.0, -9.81])         # constant force on the robot at the flange [N]
CUTOFF = ["--cutoff-hz", "10"]                # a short filter edge (0.3 s), so 8 s leave samples to score


def _motion(desc, t: np.ndarray):
    rng = np.random.default_rng(4)
    amp, freq, phase = rng.uniform(0.1, 0.3, 7), rng.uniform(0.1, 0.3, 7) * 2 * np.pi, rng.uniform(0, 6, 7)
    home = np.array([0.0, 0.6, 0.0, -1.2, 0.0, 0.9, 0.0])
    arg = freq * t[:, None] + phase
    return home + amp * np.sin(arg), amp * freq * np.cos(arg), -amp * freq ** 2 * np.sin(arg), rng


@pytest.fixture(scope="module")
def holed(tmp_path_factory) -> tuple[Recording, Path]:
    """A measured run of the nominal iiwa (its own model explains τ up to 0.05 N·m noise) pushed by a constant force,
    whose log lost the 2 s between 3 s and 5 s."""
    desc = load_robot("iiwa14_nominal")
    t = np.arange(0.0, DURATION, 1.0 / RATE)
    q, qd, qdd, rng = _motion(desc, t)
    wrench = np.tile(np.r_[FORCE, 0.0, 0.0, 0.0], (t.size, 1))
    tau = inverse_dynamics(desc, q, qd, qdd) - np.einsum("nkj,nk->nj", flange_jacobian(desc, q)[:, 3:], FORCE[None])
    tau += 0.05 * rng.standard_normal(tau.shape)
    keep = (t < HOLE[0]) | (t >= HOLE[1])
    rec = Recording(t=t[keep], q=q[keep], tau=tau[keep], f_ext=wrench[keep],
                    meta={"robot": desc.name, "source": "test_gaps_and_limits"})
    return rec, save_recording(rec, tmp_path_factory.mktemp("holed") / "holed.npz")


def inside(t: np.ndarray) -> np.ndarray:
    return (t > HOLE[0] + 1e-9) & (t < HOLE[1] - 1e-9)


# ---- 1. no invented data ------------------------------------------------------------------------------------------

def test_estimate_writes_no_value_inside_the_hole(holed, tmp_path, capsys):
    _, path = holed
    assert main(["estimate", "--model", "iiwa14_nominal", "--recording", str(path), "--out", str(tmp_path)]
                + CUTOFF) == 0
    out = capsys.readouterr().out
    with np.load(tmp_path / "estimates.npz", allow_pickle=False) as z:
        t, valid = z["t"], z["valid"].astype(bool)
        hole = inside(t)
        assert hole.sum() >= 0.99 * (HOLE[1] - HOLE[0]) * RATE          # the grid spans the hole ...
        for key in ("wrench_jacobian", "wrench_momentum", "tau_ext_jacobian", "tau_ext_momentum", "q", "f_true"):
            assert np.isnan(z[key][hole]).all(), key                     # ... but holds no value inside it
            assert np.isfinite(z[key][~z["gap"]]).all(), key
        assert not valid[hole].any() and valid.sum() > 0.4 * t.size
    csv = np.genfromtxt(tmp_path / "estimates.csv", delimiter=",", names=True)
    assert np.isnan(csv["fx_jacobian"][inside(csv["t"])]).all() and not csv["valid"][inside(csv["t"])].any()
    # the statistics are over measured samples only: the constant 15 N push is recovered to well under 1 N
    row = re.search(r"^jacobian .*$", out, re.M).group(0)               # [RMS f̂] [RMSE] [σ]
    rms, rmse = ([float(x) for x in v.split()] for v in re.findall(r"\[([^\]]+)\]", row)[:2])
    assert max(rmse) < 0.5, out
    assert np.allclose(rms, np.abs(FORCE), rtol=0, atol=max(rmse)), out  # the force RMS per axis: the push
    assert "inside gaps of the log" in out


def _page_summary(page: str) -> dict:
    return json.loads(re.search(r"id='proprio-playback'>(.*?)</script>", page, re.S).group(1).replace("<\\/", "</"))


def test_view_html_shows_nothing_inside_the_hole(holed, tmp_path, capsys):
    from test_view import animation_tracks

    _, path = holed
    html = tmp_path / "view.html"
    assert main(["view", str(path), "--html", str(html), "--model", "iiwa14_nominal"] + CUTOFF) == 0
    page = html.read_text()
    summary = _page_summary(page)
    said = re.search(r"(\d+) frames fall inside gaps of the log and show nothing", capsys.readouterr().out)
    assert said and int(said.group(1)) == summary["hidden_frames"]           # the hole is said, not only drawn
    ((a, b),) = summary["gaps_s"]
    assert a == pytest.approx(HOLE[0], abs=3 / RATE) and b == pytest.approx(HOLE[1], abs=3 / RATE)
    frame_t = np.arange(summary["frames"]) * summary["frame_period_s"]
    hidden = (frame_t > a) & (frame_t < b)
    assert summary["hidden_frames"] == hidden.sum() > 50
    tracks = animation_tracks(page)
    for path_ in ("/drake/visualizer", "/proprio/force_estimated", "/proprio/force_true"):
        shown = {k["time"]: k["value"] for k in tracks[(path_, ".visible")]}
        assert [not shown[k] for k in range(summary["frames"])] == hidden.tolist(), path_
    # no pose, arrow or tint is keyed inside the hole: nothing measured there is animated
    for (p, name), keys in tracks.items():
        if name != ".visible":
            assert not hidden[[k["time"] for k in keys]].any(), (p, name)
    # the tint scale comes from measured frames (the model explains τ up to noise and the known push: ≈ floor)
    assert summary["residual_scale_Nm"] < 0.5


def test_replay_synthesises_no_motion_inside_the_hole(holed, tmp_path, capsys):
    _, path = holed
    out = tmp_path / "replay.npz"
    assert main(["simulate", "--twin", "iiwa14_nominal_twin", "--replay", str(path), "--out", str(out),
                 "--quiet"]) == 0
    assert "2 measured stretches replayed one by one" in capsys.readouterr().out
    rep = load_recording(out)
    assert not inside(rep.t).any()                                      # no sample of the twin inside the hole
    assert rep.t[0] == pytest.approx(0.0, abs=1e-9) and rep.t[-1] == pytest.approx(DURATION - 1 / RATE, abs=1e-6)
    assert [[round(a, 2), round(b, 2)] for a, b in rep.meta["segments_s"]] == [[0.0, 3.0], [5.0, 8.0]]
    # each stretch follows the measured motion (the twin starts on it: no jump at the second stretch's start)
    src, _ = holed
    q_meas = np.stack([np.interp(rep.t, src.t, src.q[:, j]) for j in range(7)], axis=1)
    assert np.max(np.abs(rep.q - q_meas)) < 0.02


def test_identify_and_diagnose_use_no_sample_from_the_hole_or_its_filter_reach(holed):
    from proprio.conditioning import ConditioningConfig, condition
    from proprio.diagnosis.data import kept
    from proprio.identification.recordings import stack_recordings

    rec, _ = holed
    config = ConditioningConfig(cutoff_hz=10.0)
    cs = condition(rec, config)
    reach = 3.0 / 10.0                                                 # edge_cycles periods of the cutoff [s]
    near = (cs.t > HOLE[0] - reach - 1e-6) & (cs.t < HOLE[1] + reach - 1e-6)
    (q, _, _, _), _ = stack_recordings([rec], trim_s=50 / cs.rate_hz, config=config)   # 50 samples
    assert q.shape[0] == cs.n_samples - 100 - near.sum()                # identify: every such sample dropped
    assert not (kept(cs, 0.1) & near).any()                            # diagnose too
    assert kept(cs, 0.1).sum() == pytest.approx((~near).sum() - 2 * 50, abs=2)


def test_timeseries_plot_breaks_its_lines_at_the_hole(tmp_path):
    import shutil

    from proprio.timeseries_html import timeseries_html
    from test_timeseries_html import DOM, embedded

    t = np.arange(0.0, DURATION, 1.0 / RATE)
    t = t[~inside(t) & (t != HOLE[0])]
    y = np.column_stack([np.sin(t), np.cos(3 * t)])
    for max_points in (100_000, 1_000):                                # as it is, and as a min/max envelope
        frag = timeseries_html(t, {"before": y, "after": y / 2}, ["j1", "j2"], max_points=max_points)
        data = embedded(frag)
        assert data["gaps"] == [[pytest.approx(HOLE[0] - 1 / RATE), pytest.approx(HOLE[1])]]
        assert not inside(np.asarray(data["t"])).any()                  # no bucket spans the hole
    if shutil.which("node") is None:
        pytest.skip("Node.js not installed: the drawing is not checked")
    (tmp_path / "data.json").write_text(json.dumps(data))
    (tmp_path / "plot.js").write_text(re.search(r"<script>(.*?)</script>", frag, re.S).group(1))
    (tmp_path / "dom.js").write_text(DOM)
    run = subprocess.run(["node", str(tmp_path / "dom.js"), str(tmp_path / "data.json"), str(tmp_path / "plot.js")],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert [len(panel) for panel in out["first"]] == [4, 4]           # per series one line each side of the hole
    assert [len(panel) for panel in out["toggled"]] == [2, 2]


# ---- 2. plausibility at the boundary -----------------------------------------------------------------------------

@pytest.fixture()
def absurd_tau(holed, tmp_path) -> Path:
    rec, _ = holed
    tau = rec.tau.copy()
    tau[100, 2] = 1e12
    return save_recording(rec.replace(tau=tau), tmp_path / "absurd_tau.npz")


@pytest.mark.parametrize("argv", [
    ["inspect", "{rec}", "--robot", "iiwa14_nominal"],
    ["estimate", "--model", "iiwa14_nominal", "--recording", "{rec}", "--out", "{out}"],
    ["identify", "--robot", "iiwa14_nominal", "--train", "{rec}", "--out", "{out}/model.npz"],
])
def test_an_absurd_torque_is_refused_naming_the_field(absurd_tau, tmp_path, capsys, argv):
    out = tmp_path / "out"
    code = main([a.format(rec=absurd_tau, out=out) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "'tau' joint 2 (iiwa_joint_3)" in err and "effort limit 176 N·m" in err and "clipping" not in err
    assert not out.exists() or not any(out.iterdir())


def test_an_absurd_velocity_is_refused(holed):
    rec, _ = holed
    qd = np.zeros_like(rec.q)
    qd[7, 4] = -50.0
    with pytest.raises(ValueError, match=r"'qd' joint 4 .* velocity limit"):
        from proprio.recording import validate_recording
        validate_recording(rec.replace(qd=qd), load_robot("iiwa14_nominal"))


def test_over_the_limit_is_not_clipping_but_at_the_limit_is(holed):
    from proprio.data_quality import assess

    rec, _ = holed
    robot = load_robot("iiwa14_nominal")
    lim = robot.effort_limits[3]
    over = rec.tau.copy()
    over[50:60, 3] = 1.8 * lim                                         # above the limit: not a clipped sensor
    dq = assess(rec.replace(tau=over), robot)
    assert "clipping" not in dq.codes() and "over_limit" in dq.codes()
    (f,) = [f for f in dq.findings if f.code == "over_limit"]
    assert f.joints == (robot.joint_names[3],) and f.values["max_ratio"][0] == pytest.approx(1.8)
    at = rec.tau.copy()
    at[50:60, 3] = lim                                                 # sitting at the limit: clipping
    assert {"clipping"} <= assess(rec.replace(tau=at), robot).codes()


def test_an_infinite_mass_is_refused_by_the_loader(tmp_path):
    import proprio.robots

    text = (Path(proprio.robots.__file__).parent / "iiwa14_nominal.yaml").read_text()
    first = re.search(r"mass: *[0-9.]+", text).group(0)
    path = tmp_path / "inf_mass.yaml"
    path.write_text(text.replace(first, "mass: .inf", 1))
    with pytest.raises(DescriptionError, match=r"\.mass: must be a finite number, got inf"):
        load_robot(path)


def test_a_nan_payload_is_refused(tmp_path, capsys):
    assert main(["simulate", "--trajectory", "x.npz", "--payload-kg", "nan", "--out", str(tmp_path / "s.npz")]) == 2
    assert "--payload-kg" in capsys.readouterr().err
    out = tmp_path / "ds"
    assert main(["dataset", "--seeds", "1", "--payload-kg", "nan", "--scaffolds", "1", "--seconds", "1",
                 "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--payload-kg" in err and "finite" in err
    assert not list(out.rglob("*nan*"))


# ---- 5. clean shutdown and one writer per directory -------------------------------------------------------------

def _group(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid``, from /proc."""
    pids = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                fields = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pgid and fields[0] != "Z":
                pids.append(int(d))
    return pids


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_sigterm_on_dataset_leaves_no_process_and_no_temporary_file(tmp_path):
    out = tmp_path / "ds"
    cmd = [sys.executable, "-m", "proprio", "dataset", "--seeds", "1-2", "--scaffolds", "3", "--log-rate", "200",
           "--workers", "2", "--quiet", "--out", str(out)]
    with open(tmp_path / "stderr", "w") as err:      # not a pipe: an orphan holding it would block the test
        proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=err,
                                env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])})
    try:
        deadline = time.monotonic() + 120
        while len(_group(proc.pid)) < 3 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)                                           # the driver and its two workers
        assert proc.poll() is None, "the dataset finished before it could be interrupted"
        time.sleep(0.5)
        os.kill(proc.pid, signal.SIGTERM)                             # the driver only, as `kill PID` does
        proc.wait(60)
        deadline = time.monotonic() + 10
        while _group(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = _group(proc.pid)
        assert not left, f"processes left running after SIGTERM: {left}"
    finally:
        for pid in _group(proc.pid):                                  # never leave an orphan behind, pass or fail
            os.kill(pid, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, (tmp_path / "stderr").read_text()
    assert not [p for p in out.rglob(".*") if p.is_file()], sorted(out.rglob("*"))


def test_a_second_writer_is_refused_and_stale_temporaries_are_cleared(tmp_path, capsys):
    out = tmp_path / "ds"
    args = ["dataset", "--seeds", "1", "--scaffolds", "1", "--seconds", "1", "--log-rate", "200", "--quiet",
            "--out", str(out)]
    with locked_dir(out):                                             # another run is writing there
        assert main(args) == 2
        err = capsys.readouterr().err
        assert f"pid {os.getpid()}" in err and str(out) in err
        assert not list(out.glob("*.npz")) and not (out / ".tasks").exists()
        with pytest.raises(DirectoryLocked):
            with locked_dir(out):
                pass
    # a run killed outright (SIGKILL) left half-written temporaries; the next run clears them under its lock
    (out / ".tasks").mkdir()
    stale = [out / ".rfma_s1_p0kg.npz.k1ll3d00.npz", out / ".tasks" / ".rfma_s1_p0kg.npz-0.json.k1ll3d00.json"]
    for p in stale:
        p.write_bytes(b"partial")
    assert main(args) == 0
    assert (out / "rfma_s1_p0kg.npz").exists()
    assert not [p for p in out.rglob(".*") if p.is_file()], sorted(out.rglob("*"))
