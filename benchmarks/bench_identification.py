"""Identification benchmarks, printed in one run:

1. regressor throughput for 64 000 samples (samples/s) vs. a pinocchio ``computeJointTorqueRegressor`` per-sample
   loop that stores its result (ratio);
2. end-to-end OLS identification on 64 000 samples (regressor + normal equations + solve + σ%);
3. the physically consistent SDP on the same data.

Data: the twin robot (iiwa14_identified) on a random Fourier trajectory, τ from proprio.dynamics + friction + noise.
Usage: ``.venv/bin/python benchmarks/bench_identification.py [--samples 64000] [--repeats 3]``.

OpenBLAS is pinned to one thread (``OPENBLAS_NUM_THREADS=1`` unless already set): on a shared, oversubscribed
machine its spinning worker threads make the small QR/Cholesky/GEMM calls 10–100× slower; set the variable yourself
to measure multi-threaded BLAS.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from proprio import friction_law  # noqa: E402
from proprio.description import load_robot  # noqa: E402
from proprio.dynamics import inverse_dynamics  # noqa: E402
from proprio.identification.base_parameters import base_parameters  # noqa: E402
from proprio.identification.estimators import ols, sdp  # noqa: E402
from proprio.identification.excitation import FourierTrajectory  # noqa: E402
from proprio.identification.regressor import regressor  # noqa: E402


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=64_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--pinocchio-samples", type=int, default=16_000, help="samples timed in the pinocchio loop")
    args = ap.parse_args()

    robot = load_robot("iiwa14_identified")
    rng = np.random.default_rng(0)
    traj = FourierTrajectory(rng.uniform(-0.4, 0.4, (7, 5)), rng.uniform(-0.4, 0.4, (7, 5)), 0.1 * np.pi)
    t = np.linspace(0.0, 426.0, args.samples, endpoint=False)
    q, qd, qdd = traj.evaluate(t)
    tau = inverse_dynamics(robot, q, qd, qdd) + friction_law.viscous_coulomb(
        qd, np.array(robot.friction_viscous), np.array(robot.friction_coulomb)) + rng.normal(scale=0.05, size=q.shape)

    t_reg = best_of(lambda: regressor(robot, q, qd, qdd), args.repeats)
    print(f"regressor           : {args.samples} samples in {t_reg:.3f} s = {args.samples / t_reg:,.0f} samples/s "
          "(new [7, 84, N] output each call)")
    try:
        import pinocchio as pin

        from proprio.urdf import to_urdf
        model = pin.buildModelFromXML(to_urdf(robot, collision=False))
        data = model.createData()
        m = args.pinocchio_samples
        out = np.zeros((m, 7, 70))

        def loop():
            for k in range(m):
                out[k] = pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k])
        t_pin = best_of(loop, args.repeats)
        rate_pin = m / t_pin
        print(f"pinocchio loop      : {rate_pin:,.0f} samples/s (computeJointTorqueRegressor per sample, stored)")
        print(f"ratio               : {args.samples / t_reg / rate_pin:.2f}x pinocchio's loop")
    except ImportError:
        print("pinocchio loop      : pinocchio not installed")

    base = base_parameters(robot)
    t_ols = best_of(lambda: ols(robot, q, qd, qdd, tau, base=base), args.repeats)
    t_base = best_of(lambda: base_parameters(robot), args.repeats)
    print(f"OLS end-to-end      : {t_ols:.3f} s on {args.samples} samples (57 base parameters; base-parameter QR "
          f"adds {t_base:.3f} s)")
    t_sdp = best_of(lambda: sdp(robot, q, qd, qdd, tau, base=base), 1)
    print(f"SDP (Clarabel)      : {t_sdp:.3f} s on {args.samples} samples (incl. regressor + OLS)")


if __name__ == "__main__":
    main()
