"""Torque-sensor noise of the real KUKA LWR 4+ and the thesis' iiwa against the twins' configured noise.

    .venv/bin/python benchmarks/noise_calibration.py [--band 5] [--table53 REC.npz ...]

What the LWR 4+ files (``../shared/data/kuka_lwr4/measurements_{1,2,3}.npz``, 200 Hz) can show: their τ went
through a width-11 median filter and a zero-phase 6th-order 2 Hz Butterworth before it was saved (the data's
README), so nothing of the sensor's white noise above ≈2 Hz is left, and they hold no true rest (< 1 % of samples
with |q̇| < 0.005 rad/s). Printed per joint:

* ``PSD 10–40 Hz``: the median Welch PSD of τ minus its zero-phase 3 Hz trend [(N·m)²/Hz] — the filter's floor;
* ``step``: the smallest non-zero |Δτ| between samples [N·m] (any quantisation is below it);
* ``same-trajectory``: files 1 and 2 run the same trajectory; aligned in time (the shift minimising the q
  mismatch), std(τ₁ − τ₂)/√2 [N·m] is an upper bound of the sensor noise inside the files' 2 Hz band (it also
  holds run-to-run differences of friction, hysteresis and tracking; the q mismatch is printed);
* the same bound as a raw white density at 200 Hz: the files' filter chain applied to unit white noise gives the
  std it lets through (simulated), so PSD ≤ (bound / that std)² · 2/200 [(N·m)²/Hz].

The thesis' iiwa: Table 5.4's whole 0 g force error of the best hybrid, RMSE [0.08 0.09 0.12] N, bounds what the
real iiwa's sensor leaves at the flange. The twins' sensor disturbances are measured under the conditions of that
table: along its validation trajectory (30 s of RFMA, :func:`validation_trajectory`) logged at ``--rate`` (150 Hz,
6/7 ms like the thesis' robot; the logger keeps every σ-sample of the white ``torque_noise``, so the whole noise
power folds into 0–75 Hz), τ low-passed at ``--band`` Hz (zero phase: the hybrid's ``tau_filter_hz``) and mapped
through the Jacobian observer (:func:`jacobian_wrench`, f̂ = J⁻ᵀ(τ_dyn − τ_meas), force only) at every sample's q:

* the white noise by Monte Carlo (``SEEDS`` draws, RMS over them) and
* the ``ripple`` ``A sin(h·N·q + φ)`` by the effect's own law on the trajectory's q — it passes the band wherever a
  joint moves slower than ``band·2π/(h·N)`` ≈ 0.1 rad/s.

Calibration rule: both together (root sum of squares, RMS over the run) cost at most half the thesis' figure on
every axis (the other half is left to the model's error); the largest common scale of the configured σ and ripple
amplitudes that meets it is printed.

``--table53 REC.npz ...``: the irreducible floor of Table 5.3 on twin recordings (their ``truth__*`` channels,
scoring only): the hybrid's target is τ low-passed at ``TARGET_HZ`` (zero phase, as ``train_hybrid_twin``), so the
white torque noise that passes that filter is error no model can remove; the ripple that passes it is printed
beside (a function of q, learnable in principle, but at ``h·N·q̇/2π`` it mostly lies above the filter). The floor
is the MSE over samples and joints [N·m²], like the table's.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import scipy.signal

from proprio.conditioning import zero_phase_lowpass
from proprio.description import RobotDescription, load_robot
from proprio.diagrams.twin_config import TwinConfig, load_twin_config
from proprio.experiments.payload import validation_trajectory
from proprio.recording import load_recording
from proprio.signals import MotionSignals
from proprio.systems.observers import WrenchMapping, jacobian_wrench

LWR = Path(__file__).resolve().parents[2] / "shared" / "data" / "kuka_lwr4"
TREND_HZ, WHITE_BAND = 3.0, (10.0, 40.0)
HOME = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])           # a typical working pose [rad]
THESIS_0G = np.array([0.08, 0.09, 0.12])                          # Table 5.4, LSTM-2-FCL 500, 0 g, RMSE [N]
TARGET_HZ = 5.0                                                   # train_hybrid_twin's tau_filter_hz
SEEDS = 8                                                         # Monte Carlo draws of the white noise


def _load(i: int) -> dict[str, np.ndarray]:
    with np.load(LWR / f"measurements_{i}.npz", allow_pickle=False) as d:
        return {k: d[k] for k in ("times", "positions", "torques")}


def lwr_filter_floor() -> tuple[np.ndarray, np.ndarray]:
    """(median PSD 10–40 Hz of τ minus its 3 Hz trend [(N·m)²/Hz], smallest non-zero |Δτ| [N·m]) over files 1–3."""
    psd, step = [], []
    for i in (1, 2, 3):
        d = _load(i)
        fs = 1.0 / float(np.median(np.diff(d["times"])))
        resid = d["torques"] - zero_phase_lowpass(d["torques"], fs, TREND_HZ)
        f, p = scipy.signal.welch(resid, fs=fs, nperseg=int(fs), axis=0)
        psd.append(np.median(p[(f >= WHITE_BAND[0]) & (f <= WHITE_BAND[1])], axis=0))
        dtau = np.abs(np.diff(d["torques"], axis=0))
        step.append(np.where(dtau > 0, dtau, np.inf).min(0))
    return np.mean(psd, 0), np.min(step, 0)


def same_trajectory_bound(edge_s: float = 0.5) -> tuple[np.ndarray, np.ndarray, float]:
    """(std(τ₁ − τ₂)/√2 [N·m], RMS q mismatch [deg], shift [s]) of files 1 and 2 aligned in time."""
    a, b = _load(1), _load(2)
    t1, t2 = a["times"] - a["times"][0], b["times"] - b["times"][0]
    shifts = np.arange(-0.5, 0.5, 0.001)
    inner = (t1 > edge_s) & (t1 < t1[-1] - 1.0)

    def resample(x: np.ndarray, s: float) -> np.ndarray:
        return np.stack([np.interp(t1[inner] + s, t2, x[:, j]) for j in range(x.shape[1])], axis=1)

    cost = [np.mean((a["positions"][inner] - resample(b["positions"], s)) ** 2) for s in shifts]
    s = float(shifts[int(np.argmin(cost))])
    dq = a["positions"][inner] - resample(b["positions"], s)
    dtau = a["torques"][inner] - resample(b["torques"], s)
    return dtau.std(0) / np.sqrt(2.0), np.degrees(np.sqrt((dq ** 2).mean(0))), s


def filter_chain_gain(fs: float = 200.0, n: int = 200_000, seed: int = 0) -> float:
    """Std of unit white noise at ``fs`` after the LWR files' τ filter chain (median 11, zero-phase 6th-order
    Butterworth at 2 Hz)."""
    x = scipy.signal.medfilt(np.random.default_rng(seed).standard_normal(n), 11)
    return float(scipy.signal.sosfiltfilt(scipy.signal.butter(6, 2.0, fs=fs, output="sos"), x).std())


def force_floor(desc: RobotDescription, sigma_band: np.ndarray, q: np.ndarray, n: int = 20000, seed: int = 0
                ) -> np.ndarray:
    """Std [N] of f̂ along x, y, z when τ carries independent noise of ``sigma_band`` [N·m] per joint at pose q."""
    noise = np.random.default_rng(seed).standard_normal((n, desc.n)) * sigma_band
    wrench, _, _ = jacobian_wrench(desc, np.tile(q, (n, 1)), noise, np.zeros_like(noise),
                                   WrenchMapping(force_only=True))
    return wrench[:, :3].std(0)


def sensor_force(twin: TwinConfig, band: float, rate: float, seconds: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """``(noise, ripple)``: RMS [N] along x, y, z at the flange of the twin's white torque noise and its ripple on
    Table 5.4's validation run (``seconds`` [s] logged at ``rate`` [Hz], τ low-passed at ``band`` [Hz], force-only
    Jacobian observer); zeros for an effect the twin does not have."""
    traj = validation_trajectory(seconds)
    t = np.arange(traj.start_time(), traj.end_time(), 1.0 / rate)
    q = traj.vector_values(t).T
    zero = np.zeros_like(q)

    def flange_rms(tau: np.ndarray) -> np.ndarray:
        wrench, _, _ = jacobian_wrench(twin.robot, q, zero_phase_lowpass(tau, rate, band), zero,
                                       WrenchMapping(force_only=True))
        return np.sqrt(np.mean(wrench[:, :3] ** 2, axis=0))

    noise, ripple = twin.effect("torque_noise"), twin.effect("ripple")
    noise_rms = np.zeros(3) if noise is None else np.sqrt(np.mean(
        [flange_rms(np.random.default_rng(s).standard_normal(q.shape) * noise.std) ** 2 for s in range(SEEDS)], axis=0))
    ripple_rms = np.zeros(3) if ripple is None else flange_rms(ripple.torque(MotionSignals(t, q, zero, zero)))
    return noise_rms, ripple_rms


def table53_floor(path: Path) -> tuple[float, float]:
    """``(noise, noise + ripple)``: the MSE [N·m²] of the twin recording's truth noise (and ripple) through the
    hybrid target's ``TARGET_HZ`` zero-phase low-pass, over samples and joints."""
    rec = load_recording(path)
    noise, ripple = rec.truth["tau_torque_noise"], rec.truth["tau_ripple"]
    rate = (rec.n_samples - 1) / (rec.t[-1] - rec.t[0])      # the mean rate: a 150 Hz log alternates 6 and 7 ms steps
    lp = lambda x: zero_phase_lowpass(x, rate, TARGET_HZ)  # noqa: E731
    return float(np.mean(lp(noise) ** 2)), float(np.mean(lp(noise + ripple) ** 2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--band", type=float, default=TARGET_HZ, help="bandwidth the force estimate keeps [Hz]")
    ap.add_argument("--rate", type=float, default=150.0, help="log rate of Table 5.4's run [Hz]")
    ap.add_argument("--seconds", type=float, default=30.0,
                    help="duration of Table 5.4's run [s] (the rule's 30; the thesis' run lasted 563)")
    ap.add_argument("--table53", nargs="+", type=Path, default=[], metavar="REC",
                    help="twin recordings (.npz with truth channels): print the Table 5.3 floor of each")
    args = ap.parse_args()
    fmt = lambda v, p=3: "[" + " ".join(f"{x:.{p}g}" for x in v) + "]"  # noqa: E731
    for path in args.table53:
        noise, both = table53_floor(path)
        print(f"{path}: Table 5.3 floor (τ target low-passed at {TARGET_HZ:g} Hz) {noise:.3g} N·m² from the torque "
              f"noise, {both:.3g} N·m² with the ripple")
    if args.table53:
        return
    psd, step = lwr_filter_floor()
    bound, dq, shift = same_trajectory_bound()
    gain = filter_chain_gain()
    print("LWR 4+ files (τ median-11 + 2 Hz zero-phase filtered before saving):")
    print(f"  PSD {WHITE_BAND[0]:g}-{WHITE_BAND[1]:g} Hz of τ minus its {TREND_HZ:g} Hz trend [(N·m)²/Hz]: {fmt(psd)}")
    print(f"  smallest non-zero |Δτ| [N·m]: {fmt(step)}")
    print(f"  files 1 vs 2 (same trajectory, shift {shift * 1e3:.0f} ms, q mismatch RMS {fmt(dq, 2)} deg): "
          f"std(Δτ)/√2 [N·m] = {fmt(bound)} (upper bound of the noise inside ≈2 Hz)")
    print(f"  the filter chain passes {gain:.3f} of unit white noise at 200 Hz → raw white PSD ≤ "
          f"{fmt((bound / gain) ** 2 * 2 / 200)} (N·m)²/Hz")
    print(f"  that bound at the LWR's flange at q = {fmt(HOME, 2)} rad [N]: "
          f"{fmt(force_floor(load_robot(str(LWR)), bound, HOME))}")
    print(f"thesis Table 5.4, best hybrid at 0 g (iiwa, whole error) RMSE [N]: {fmt(THESIS_0G)}; "
          f"noise budget (half) {fmt(THESIS_0G / 2)}")
    for name in ("iiwa14_twin", "kuka_lwr4_twin"):
        twin = load_twin_config(name)
        noise, ripple = twin.effect("torque_noise"), twin.effect("ripple")
        if noise is None and ripple is None:
            print(f"{name}: no torque_noise, no ripple (a noiseless sensor, quieter than any real one)")
            continue
        n_rms, r_rms = sensor_force(twin, args.band, args.rate, args.seconds)
        both = np.hypot(n_rms, r_rms)
        std = np.broadcast_to(np.asarray(noise.std if noise else 0.0, float), (twin.robot.n,))
        amp = np.hypot(ripple.sin_amplitude, ripple.cos_amplitude) if ripple else np.zeros(twin.robot.n)
        print(f"{name}: white σ {fmt(std)} N·m per sample, ripple amplitude {fmt(amp)} N·m; on Table 5.4's run "
              f"({args.seconds:g} s at {args.rate:g} Hz, τ inside {args.band:g} Hz) at the flange [N]: noise "
              f"{fmt(n_rms)}, ripple {fmt(r_rms)}, together {fmt(both)}; largest common scale within the budget: "
              f"{np.min(THESIS_0G / 2 / both):.2f}")


if __name__ == "__main__":
    main()
