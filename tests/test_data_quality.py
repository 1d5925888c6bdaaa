"""Data-quality findings (proprio.data_quality): each check fires on a Recording built with its defect and stays
silent on a clean twin-like log; the real LWR 4+ files are flagged as τ-filtered upstream with a q̇ lag of a few ms;
the CSV importer merges duplicated time stamps."""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.signal

from proprio.data_quality import (
    DataQuality,
    Finding,
    assess,
    findings_markdown,
    format_findings,
    quantisation_step,
    runs,
)
from proprio.description import robot_from_mdh
from proprio.recording import Recording, load_lwr4, recording_from_csv

RATE = 1000.0
N_J = 3
FREQ = np.array([[0.21, 0.53, 1.3], [0.17, 0.61, 1.1], [0.29, 0.47, 1.7]])    # Hz, per joint × 3 sinusoids
AMP = np.array([[0.6, 0.15, 0.03], [0.5, 0.2, 0.02], [0.7, 0.1, 0.04]])       # rad


def motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, q̇, q̈ of smooth multi-sine joint motion [rad, rad/s, rad/s²] at the times ``t`` [s]."""
    w = 2 * np.pi * FREQ
    arg = t[:, None, None] * w[None]
    q = np.sum(AMP * np.sin(arg), axis=2)
    qd = np.sum(AMP * w * np.cos(arg), axis=2)
    qdd = -np.sum(AMP * w ** 2 * np.sin(arg), axis=2)
    return q, qd, qdd


def twin_like(seconds: float = 20.0, rate: float = RATE, seed: int = 0, q_noise: float = 1e-5,
              tau_noise: float = 0.3, qd: bool = True, t: np.ndarray | None = None) -> Recording:
    """A clean twin-like log: uniform stamps, q with white encoder noise, τ = a smooth load + white sensor noise,
    and the exact q̇ (what a twin's logger would give as the robot's own velocity)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate if t is None else t
    q, qd_, qdd = motion(t)
    tau = 20.0 * np.sin(q) + 2.0 * qdd + 0.5 * qd_ + tau_noise * rng.standard_normal(q.shape)
    return Recording(t=t, q=q + q_noise * rng.standard_normal(q.shape), tau=tau, qd=qd_ if qd else None,
                     meta={"source": "synthetic twin-like log"})


@pytest.fixture(scope="module")
def clean() -> DataQuality:
    return assess(twin_like())


ALL_DEFECT_CODES = {"jitter", "gap", "duplicates", "clipping", "flat_top", "quantised", "tau_filtered", "qd_lag",
                    "qd_gain", "qdd_recorded", "conditioning"}


def test_clean_twin_like_log_has_no_defects(clean):
    assert not clean.codes() & ALL_DEFECT_CODES, format_findings(clean)
    assert clean.worst == "info" and not clean.at_least("warning")
    assert "qd_consistent" in clean.codes()             # it has a q̇, and it agrees with dq/dt
    assert clean.conditioning.startswith("conditioning: 1000 Hz uniform grid")


# ---- time base ----------------------------------------------------------------------------------------------------

def test_jitter_and_gaps():
    rng = np.random.default_rng(1)
    dt = np.full(20000, 1e-3)
    dt += rng.uniform(-2e-4, 2e-4, dt.size)
    long_ = rng.random(dt.size) < 0.02                  # ~2 % of steps 1.5–8.5 ms, like a real FRI log
    dt[long_] = rng.uniform(1.6e-3, 8.5e-3, long_.sum())
    t = np.concatenate([[0.0], np.cumsum(dt)])
    dq = assess(twin_like(t=t))
    (f,) = [f for f in dq.findings if f.code == "jitter"]
    assert f.severity == "warning" and f.channel == "t"
    assert f.values["long_step_fraction"] == pytest.approx(long_.mean(), abs=2e-3)
    assert f.values["dt_max_s"] == pytest.approx(dt.max()) and "gap" not in dq.codes()
    # a 60 ms and a 200 ms dropout
    t2 = np.arange(20000) / RATE
    t2 = np.delete(t2, np.r_[5000:5059, 12000:12199])
    dq2 = assess(twin_like(t=t2))
    (g,) = [f for f in dq2.findings if f.code == "gap"]
    assert g.severity == "warning" and g.values["gaps"] == 2
    assert g.values["missing_s"] == pytest.approx(0.059 + 0.199, abs=1e-6)
    np.testing.assert_allclose(g.values["gap_start_s"], [4.999, 11.999], atol=1e-9)
    assert "2 gap(s)" in g.message and "t = 4.999" in g.message
    assert "jitter" in dq2.codes()                      # a gap is an uneven step too
    assert "gap" not in assess(twin_like()).codes()


def test_csv_duplicate_stamps_are_averaged_and_reported(tmp_path):
    t = np.arange(200) * 0.005
    q = np.linspace(0, 1, 200)[:, None] * [1.0, -0.5]
    tau = np.sin(np.arange(200) * 0.1)[:, None] * [2.0, 1.0]
    rows = np.hstack([t[:, None], q, tau])
    dup = np.insert(rows, [51, 51, 120], rows[[50, 50, 119]] + [0, 0.01, 0.02, 0.1, 0.2], axis=0)
    np.savetxt(tmp_path / "dup.csv", dup, delimiter=",", header="t,q1,q2,tau1,tau2", comments="")
    rec = recording_from_csv(tmp_path / "dup.csv", 2)
    assert rec.n_samples == 200
    assert rec.meta["duplicate_stamps"] == {"stamps": 2, "samples": 5, "first_t": pytest.approx(0.25)}
    np.testing.assert_allclose(rec.q[50], q[50] + [0.01 * 2 / 3, 0.02 * 2 / 3])          # mean of 3 rows
    np.testing.assert_allclose(rec.tau[119], tau[119] + [0.05, 0.1])                     # mean of 2 rows
    np.testing.assert_array_equal(rec.q[:50], q[:50])
    (f,) = [f for f in assess(rec).findings if f.code == "duplicates"]
    assert f.severity == "warning" and "2 duplicated time stamp(s) (5 samples)" in f.message
    # time that runs backwards is still an error, not merged
    back = rows.copy()
    back[[10, 11], 0] = back[[11, 10], 0]
    np.savetxt(tmp_path / "back.csv", back, delimiter=",", header="t,q1,q2,tau1,tau2", comments="")
    with pytest.raises(ValueError, match="not strictly increasing"):
        recording_from_csv(tmp_path / "back.csv", 2)
    assert "duplicate_stamps" not in recording_from_csv(tmp_path / "dup.csv", 2).replace(meta={}).meta


# ---- torque -------------------------------------------------------------------------------------------------------

def small_robot(effort: list[float]):
    return robot_from_mdh([0.0, np.pi / 2, -np.pi / 2], [0, 0, 0], [0.3, 0, 0.4], effort=effort)


def test_clipping_at_the_effort_limit():
    rec = twin_like()
    robot = small_robot([50.0, 30.0, 40.0])
    assert "clipping" not in assess(rec, robot).codes()
    tau = rec.tau.copy()
    tau[:, 1] = np.clip(tau[:, 1] * 3.0, -29.8, 29.8)                   # within 1 % of ±30 N·m
    dq = assess(rec.replace(tau=tau), robot)
    (f,) = [f for f in dq.findings if f.code == "clipping"]
    assert f.severity == "problem" and f.joints == (robot.joint_names[1],)
    assert f.values["effort_limit_nm"] == [30.0] and f.values["samples"][0] >= 100
    assert "±30 N·m" in f.message and robot.joint_names[1] in f.message


def test_flat_top_saturation_but_not_a_quantised_smooth_peak():
    rec = twin_like()
    tau = rec.tau.copy()
    tau[:, 0] = np.minimum(tau[:, 0], 12.0)                             # a sensor saturating at 12 N·m
    dq = assess(rec.replace(tau=tau))
    (f,) = [f for f in dq.findings if f.code == "flat_top"]
    assert f.severity == "problem" and f.joints == ("j1",) and f.values["level_nm"] == [12.0]
    # a noise-free, coarsely quantised torque sits at its peak level for many samples, but creeps in one step
    smooth = np.round(20.0 * np.sin(rec.q) / 0.05) * 0.05
    assert "flat_top" not in assess(rec.replace(tau=smooth)).codes()
    assert "flat_top" not in assess(rec).codes()


def test_quantisation_steps_of_q_and_tau():
    rec = twin_like()
    step_q = np.radians(0.001)
    q = np.round(rec.q / step_q) * step_q
    tau = np.round(rec.tau / 0.01) * 0.01
    dq = assess(rec.replace(q=q, tau=tau))
    fq, ft = [f for f in dq.findings if f.code == "quantised"]
    assert (fq.channel, ft.channel) == ("q", "tau") and fq.severity == ft.severity == "info"
    np.testing.assert_allclose(fq.values["step"], step_q, rtol=1e-6)
    np.testing.assert_allclose(fq.values["step_deg"], 0.001, rtol=1e-6)
    np.testing.assert_allclose(ft.values["step"], 0.01, rtol=1e-6)
    assert "0.001°" in fq.message and "0.01 N·m" in ft.message and "all 3 joints" in fq.message
    # a coarse encoder: most samples repeat their predecessor -> warning
    coarse = np.round(rec.q / 1e-3) * 1e-3
    (fc,) = [f for f in assess(rec.replace(q=coarse)).findings if f.code == "quantised"]
    assert fc.severity == "warning" and "coarse" in fc.message
    np.testing.assert_allclose(fc.values["step"], 1e-3, rtol=1e-6)
    # continuous values have no step
    assert quantisation_step(rec.q[:, 0]) is None and quantisation_step(rec.tau[:, 0]) is None


def test_quantisation_step_when_single_steps_are_rare():
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.choice([-4, -2, 2, 4, 6], size=5000)) * 0.125 + 0.5 * 3   # only even multiples of 0.125
    x[::97] += 0.125                                                             # a few odd ones
    assert quantisation_step(x) == pytest.approx(0.125)


def test_tau_filtered_upstream():
    rec = twin_like()
    sos = scipy.signal.butter(6, 2.0, fs=RATE, output="sos")
    filt = scipy.signal.sosfiltfilt(sos, rec.tau, axis=0)
    dq = assess(rec.replace(tau=filt))
    (f,) = [f for f in dq.findings if f.code == "tau_filtered"]
    assert f.severity == "warning" and f.joints == ("j1", "j2", "j3")
    assert np.all(np.asarray(f.values["minus_60db_above_hz"]) < 20.0)
    # a mild filter near Nyquist (an anti-alias stage) on white noise is also "filtered": the spectrum falls
    sos2 = scipy.signal.butter(4, 100.0, fs=RATE, output="sos")
    assert "tau_filtered" in assess(rec.replace(tau=scipy.signal.sosfiltfilt(sos2, rec.tau, axis=0))).codes()
    # white sensor noise, at 1 kHz or decimated to 150 Hz-like rates, is not
    assert "tau_filtered" not in assess(rec).codes()
    assert "tau_filtered" not in assess(twin_like(rate=150.0, seconds=60.0)).codes()


# ---- derivatives --------------------------------------------------------------------------------------------------

def test_qd_lag_and_gain():
    rec = twin_like()
    _, qd_late, _ = motion(rec.t - 0.003)                               # the robot's q̇ 3 ms late
    dq = assess(rec.replace(qd=qd_late))
    (f,) = [f for f in dq.findings if f.code == "qd_lag"]
    assert f.severity == "warning" and f.values["lag_s"] == pytest.approx(0.003, abs=2e-4)
    np.testing.assert_allclose(f.values["lag_per_joint_s"], 0.003, atol=3e-4)
    assert "lags dq/dt by 3" in f.message
    _, qd_early, _ = motion(rec.t + 0.002)
    (e,) = [f for f in assess(rec.replace(qd=qd_early)).findings if f.code == "qd_lag"]
    assert e.values["lag_s"] == pytest.approx(-0.002, abs=2e-4) and "leads" in e.message
    dq_gain = assess(rec.replace(qd=rec.qd * np.array([1.0, 0.9, 1.0])))
    (g,) = [f for f in dq_gain.findings if f.code == "qd_gain"]
    assert g.joints == ("j2",) and g.values["gain_per_joint"][1] == pytest.approx(0.9, abs=0.005)
    assert "qd_lag" not in dq_gain.codes()
    (c,) = [f for f in assess(rec).findings if f.code == "qd_consistent"]
    assert abs(c.values["lag_s"]) < 2e-4
    np.testing.assert_allclose(c.values["gain_per_joint"], 1.0, atol=0.005)
    assert not {"qd_lag", "qd_gain", "qd_consistent"} & assess(rec.replace(qd=None)).codes()


def test_qdd_noise_and_recorded_channel():
    noisy = twin_like(q_noise=2e-5)
    (f,) = [f for f in assess(noisy).findings if f.code == "qdd_noise"]
    raw = np.gradient(np.gradient(noisy.q, noisy.t, axis=0), noisy.t, axis=0)
    np.testing.assert_allclose(f.values["raw_rms_rad_s2"], np.sqrt(np.mean(raw ** 2, axis=0)))
    true_rms = np.sqrt(np.mean(motion(noisy.t)[2] ** 2, axis=0))
    np.testing.assert_allclose(f.values["conditioned_rms_rad_s2"], true_rms, rtol=0.05)
    assert np.all(np.asarray(f.values["raw_rms_rad_s2"]) > 3 * true_rms)
    assert "qdd_noise" not in assess(twin_like(q_noise=0.0)).codes()
    assert "qdd_recorded" in assess(noisy.replace(qdd=motion(noisy.t)[2])).codes()
    assert "qdd_recorded" not in assess(noisy).codes()


def test_too_short_for_conditioning_is_a_finding_not_a_crash():
    dq = assess(twin_like(seconds=0.05))
    assert "conditioning" in dq.codes() and dq.conditioning.startswith("conditioning: not possible")


# ---- forms --------------------------------------------------------------------------------------------------------

def test_text_markdown_and_json_forms(clean):
    rec = twin_like()
    tau = rec.tau.copy()
    tau[:, 0] = np.minimum(tau[:, 0], 12.0)
    bad = assess(rec.replace(tau=tau))
    text = format_findings(bad, title="data quality")
    lines = text.splitlines()
    assert lines[0] == "data quality" and lines[1].startswith("  PROBLEM  flat_top")
    assert lines[-1].startswith("  conditioning: ")
    short = format_findings(clean, min_severity="warning")
    assert "no findings of severity warning or worse" in short and "INFO" not in short
    md = findings_markdown([("train 1", bad), ("held-out 1", clean)], min_severity="warning")
    assert md.startswith("| recording | severity | finding | what |")
    assert "| train 1 | problem | flat_top |" in md and "| held-out 1 | — | — | no findings |" in md
    assert "held-out 1 (synthetic twin-like log) — conditioning:" in md
    d = json.loads(bad.to_json())
    assert d["findings"][0]["code"] == "flat_top" and d["findings"][0]["values"]["level_nm"] == [12.0]
    with pytest.raises(ValueError, match="severity"):
        Finding("fatal", "x", "x", "t")


def test_runs():
    m = np.array([0, 1, 1, 0, 1, 1, 1, 0, 1], dtype=bool)
    np.testing.assert_array_equal(runs(m), [[1, 3], [4, 7], [8, 9]])
    np.testing.assert_array_equal(runs(m, 3), [[4, 7]])


# ---- the real LWR 4+ files -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("index", [1, 2, 3])
def test_lwr_files_tau_filtered_and_qd_lag(lwr_dir, index):
    from proprio.description import load_robot
    robot = load_robot(lwr_dir)
    dq = assess(load_lwr4(lwr_dir, index), robot)
    (f,) = [f for f in dq.findings if f.code == "tau_filtered"]
    assert f.joints == tuple(robot.joint_names)                        # every joint: filtered at 2 Hz upstream
    (lag,) = [f for f in dq.findings if f.code == "qd_lag"]
    assert 1e-3 <= lag.values["lag_s"] <= 6e-3, lag.message            # README: about 3 ms
    assert not {"clipping", "flat_top", "gap", "quantised"} & dq.codes()
