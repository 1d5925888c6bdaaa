"""Benchmark: the full-size RFMA path of §4.3 (150 scaffolds, ≈337 500 waypoints, ≈1 h of motion).

Prints the time to generate the geometric path (scaffold sampling + ordering + explorations), the time to
time-parameterise it into a Drake PiecewisePolynomial, waypoints/s, and the resulting motion's key figures.
Run: ``.venv/bin/python benchmarks/bench_rfma.py [--scaffolds 150] [--seed 0]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from proprio.description import load_robot
from proprio.systems.rfma import generate_rfma_path, load_rfma_config, rfma_trajectory
from proprio.collision import CollisionChecker
from proprio.systems.trajectories import check_limits, sample_trajectory


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scaffolds", type=int, default=150)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    cfg = load_rfma_config(scaffolds=args.scaffolds, seed=args.seed)
    desc = load_robot(cfg.robot)

    t0 = time.perf_counter()
    path = generate_rfma_path(desc, cfg)
    t1 = time.perf_counter()
    timed = rfma_trajectory(path, desc, cfg)
    t2 = time.perf_counter()

    n_wp = path.waypoints.shape[0]
    durations = np.diff(timed.phase_times)
    kinds = np.array(timed.phase_kinds)
    lim = check_limits(timed.trajectory, desc, rate_hz=200.0)
    print(f"RFMA full-size path: {path.n_scaffolds} scaffolds ({path.tries} candidates drawn), {n_wp} waypoints")
    print(f"  path generation         {t1 - t0:7.2f} s   ({n_wp / (t1 - t0):,.0f} waypoints/s)")
    print(f"  time parameterisation   {t2 - t1:7.2f} s   ({n_wp / (t2 - t1):,.0f} waypoints/s, "
          f"{timed.trajectory.get_number_of_segments()} cubic segments)")
    print(f"  total                   {t2 - t0:7.2f} s   ({n_wp / (t2 - t0):,.0f} waypoints/s)  [target < 60 s]")
    print(f"  motion: {timed.duration:.0f} s ({timed.duration / 3600:.2f} h); "
          f"reach phases {durations[kinds == 'reach'].sum():.0f} s, "
          f"explore phases {durations[kinds == 'explore'].sum():.0f} s "
          f"(mean {durations[kinds == 'explore'].mean():.1f} s each)")
    print(f"  limits (200 Hz check): max |qd|/v = {lim['velocity']:.3f}, max |qdd|/a = {lim['acceleration']:.3f}, "
          f"position margin {np.degrees(-lim['position_excess_rad']):.2f} deg")
    limit_scaled = sum(1 for s in path.scaled if np.isfinite(s[2]))
    shrunk = len({s[0] for s in path.scaled if not np.isfinite(s[2])})
    print(f"  exploration joints scaled to stay inside the joint limits: {limit_scaled} of "
          f"{path.n_scaffolds * desc.n}; explorations shrunk to avoid a collision: {shrunk} of {path.n_scaffolds}")
    retracts = sum(1 for k in timed.phase_kinds if k == "reach") - path.n_scaffolds - int(cfg.return_home)
    _, q10, _, _ = sample_trajectory(timed.trajectory, 10.0)
    in_collision = CollisionChecker(desc, cfg.boxes).in_collision(q10)
    print(f"  reaches: {path.reach_rejections} nearest scaffolds passed over (colliding reach), {retracts} retracts "
          f"home; trajectory samples in collision at 10 Hz: {int(in_collision.sum())} of {q10.shape[0]}")


if __name__ == "__main__":
    main()
