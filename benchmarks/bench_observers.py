"""Cost of the wrench observers: µs per step inside the estimation diagram, and samples/s of the offline paths.

Run: ``.venv/bin/python benchmarks/bench_observers.py`` (prints a table; 2 cores shared → take the best of 3).
"""
from __future__ import annotations

import time

import numpy as np

from proprio.description import load_robot
from proprio.diagrams.estimation import (RigidBodyTorqueModel, build_estimation_diagram, estimate_wrench_offline,
                                         conditioned_signals, run_estimation_diagram)
from proprio.dynamics import inverse_dynamics
from proprio.payload import Payload, attach_payload
from proprio.recording import Recording
from proprio.momentum import momentum_observer
from proprio.systems.observers import jacobian_wrench


def _recording(seconds: float = 5.0, h: float = 1e-3) -> Recording:
    rng = np.random.default_rng(0)
    t = np.arange(0.0, seconds, h)
    amp, freq, phase = rng.uniform(0.05, 0.2, 7), rng.uniform(0.5, 2.0, 7), rng.uniform(0, 6, 7)
    home = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
    arg = freq * t[:, None] + phase
    q, qd, qdd = home + amp * np.sin(arg), amp * freq * np.cos(arg), -amp * freq ** 2 * np.sin(arg)
    desc = load_robot("iiwa14_identified")
    tau = inverse_dynamics(attach_payload(desc, Payload(1.0)), q, qd, qdd)
    return Recording(t=t, q=q, tau=tau, meta={"robot": desc.name})


def _best(fn, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    desc = load_robot("iiwa14_identified")
    model = RigidBodyTorqueModel(desc)
    rec = _recording()
    n = rec.n_samples
    _, sig, _ = conditioned_signals(rec)

    def run_diagram():
        run_estimation_diagram(*build_estimation_diagram(model, sig), sig["t"][-1], sig["time_step"])

    diag_s = _best(run_diagram)
    jac_s = _best(lambda: jacobian_wrench(desc, sig["q"], sig["tau"], sig["tau"]))
    mom_s = _best(lambda: momentum_observer(desc, sig["time_step"], sig["q"], sig["qd"], sig["tau"]))
    off_s = _best(lambda: estimate_wrench_offline(model, rec))
    print(f"{n} samples at 1 kHz ({rec.duration:.1f} s of data), iiwa14, best of 3")
    print(f"{'path':<52}{'µs/sample':>12}{'real-time factor':>18}")
    for name, sec in (("estimation diagram (model + both observers + log)", diag_s),
                      ("jacobian_wrench, vectorised", jac_s), ("momentum_observer, vectorised", mom_s),
                      ("estimate_wrench_offline (filters + model + both)", off_s)):
        print(f"{name:<52}{sec / n * 1e6:>12.1f}{rec.duration / sec:>17.1f}x")


if __name__ == "__main__":
    main()
