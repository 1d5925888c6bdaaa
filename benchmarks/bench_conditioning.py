"""The conditioning path against the twin's truth: q̇ and q̈ errors on twin logs at 150 Hz, 200 Hz and 1 kHz.

    .venv/bin/python benchmarks/bench_conditioning.py [--seconds 40] [--seed 3]

One RFMA trajectory (``--seed``) runs once per rate on the calibrated twin (``iiwa14_twin``: shipped encoder noise
0.0005° and 0.0001° quantisation, its logger's jittered stamps and lost samples, q and τ only). Each log goes through
:func:`proprio.conditioning.condition` (auto cutoff per joint); its q̇, q̈ are compared with the twin's exact ones
(``truth__qd``, ``truth__qdd``, interpolated onto the uniform grid) away from the filter edges. Printed per rate:
the RMS error over joints (mean and worst joint), relative to the signal's RMS, the conditioning's own error estimate
(``sigma_qd``, ``sigma_qdd``: an honest estimate should be of the same order) and, for reference, the error of raw
second-order differences of q at the log's own stamps (``np.gradient``), which is what a pipeline without the
low-pass gets.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.interpolate

from proprio.conditioning import condition
from proprio.diagrams.twin import load_twin_config, simulate_twin
from proprio.systems.rfma import generate_rfma, load_rfma_config
from proprio.systems.trajectories import truncate_trajectory

RATES = (150.0, 200.0, 1000.0)


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(x ** 2, axis=0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=40.0, help="seconds of RFMA motion per log (default 40)")
    ap.add_argument("--seed", type=int, default=3, help="RFMA seed (default 3)")
    args = ap.parse_args()
    twin = load_twin_config("iiwa14_twin")
    _, timed = generate_rfma(load_rfma_config(scaffolds=3, seed=args.seed), twin.robot)
    traj = truncate_trajectory(timed.trajectory, args.seconds)
    print(f"calibrated twin, RFMA seed {args.seed}, {args.seconds:g} s per log; logger: jitter "
          f"{twin.logger.stamp_jitter_ms} ms, dropout {twin.logger.dropout_prob}/sample; q and τ only")
    head = (f"{'rate':>7} {'cutoff [Hz]':>13} {'q̇ RMS err':>10} {'worst':>8} {'rel':>6} {'σ̂(q̇)':>8} "
            f"{'raw Δ':>8} | {'q̈ RMS err':>10} {'worst':>8} {'rel':>6} {'σ̂(q̈)':>8} {'raw Δ²':>9} {'s':>5}")
    print(head)
    print(f"{'[Hz]':>7} {'min–max':>13} {'[rad/s]':>10} {'':>8} {'':>6} {'':>8} {'':>8} | {'[rad/s²]':>10}")
    for rate in RATES:
        rec = simulate_twin(twin.with_logger(rate_hz=rate), traj, progress=False)
        t0 = time.perf_counter()
        cs = condition(rec)
        took = time.perf_counter() - t0
        t_true = rec.truth["t_true"]
        qd = scipy.interpolate.make_interp_spline(t_true, rec.truth["qd"], k=3, axis=0)(cs.t)
        qdd = scipy.interpolate.make_interp_spline(t_true, rec.truth["qdd"], k=3, axis=0)(cs.t)
        edge = int(np.ceil(3.0 * cs.rate_hz / cs.cutoff_hz.min()))
        inner = np.zeros(cs.n_samples, dtype=bool)
        inner[edge:-edge] = True
        inner &= cs.valid
        e_qd, e_qdd = _rms((cs.qd - qd)[inner]), _rms((cs.qdd - qdd)[inner])
        raw_qd = np.gradient(rec.q, rec.t, axis=0)
        raw_qdd = np.gradient(raw_qd, rec.t, axis=0)
        sl = slice(edge, -edge)
        r_qd, r_qdd = _rms((raw_qd - rec.truth["qd"])[sl]), _rms((raw_qdd - rec.truth["qdd"])[sl])
        s_qd, s_qdd = _rms(qd[inner]), _rms(qdd[inner])
        print(f"{rate:7.0f} {cs.cutoff_hz.min():6.1f}–{cs.cutoff_hz.max():<6.1f} {e_qd.mean():10.2e} "
              f"{e_qd.max():8.1e} {np.mean(e_qd / s_qd):6.1%} {cs.sigma_qd.mean():8.1e} {r_qd.mean():8.1e} | "
              f"{e_qdd.mean():10.2e} {e_qdd.max():8.1e} {np.mean(e_qdd / s_qdd):6.1%} {cs.sigma_qdd.mean():8.1e} "
              f"{r_qdd.mean():9.1e} {took:5.2f}")
    print("rel: error RMS / signal RMS, mean over joints; σ̂: the conditioning's own estimate (mean over joints); "
          "raw: np.gradient of q at its stamps; s: conditioning time")


if __name__ == "__main__":
    main()
