"""Twin benchmark: real-time factor of the whole twin (dynamics, sensors and logger in one Diagram) with all effects on
at 1 kHz against the dynamics-only Diagram in the same run, the projected wall time of the full 1 h RFMA path, and the
calibration check of issue 4 (identified-style RBD model vs. twin data, next to thesis Table 5.3).

    .venv/bin/python benchmarks/bench_twin.py                          # 6-scaffold RFMA (~200 s of motion)
    .venv/bin/python benchmarks/bench_twin.py --scaffolds 150          # the full ≈1 h path (slow)
    .venv/bin/python benchmarks/bench_twin.py --trajectory FILE.npz    # any 'proprio trajectory rfma' file
    .venv/bin/python benchmarks/bench_twin.py --coupled                # only the coupled-drive twin (TX40), below

Prints, by CPU time of this process (load-independent, the figure the targets use) and by wall time: the dynamics-only
Diagram (trajectory source, controller, drive, plant; no sensors, no logger), run before and after the whole twin,
and the whole twin (``simulate_twin``: the same Diagram with the measurement chain, to the Recording its logger
wrote), as real-time factors, µs per 1 ms step and the twin's share of the dynamics-only figure; the projection to a
3600 s path, and per-joint MSE [N·m²] of ``τ_RBD + F_v q̇ + F_c
sign(q̇)`` (true inertials and friction of the twin's robot, true q̇/q̈) against the measured τ_J — raw and with the
white noise removed — beside the thesis' RBD test row.

``--coupled`` prints instead the coupled-drive twin's figure (:func:`coupled_drive`): ``staubli_tx40_twin`` (motor 6
turns with joints 5 and 6: rotor inertia ``CᵀI_aC`` off the diagonal, solved implicitly each 0.1 ms step) on a
seeded 10 s path, its real-time factor by CPU time, and the same arm and path with the coupling dropped (diagonal
rotor inertia, every per-step System compiled) as the same-run reference.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from proprio.diagrams.twin import build_twin_diagram, load_twin_config, simulate_twin, start_simulator
from proprio.dynamics import inverse_dynamics

THESIS_RBD_TEST_MSE = np.array([2.0882, 23.1839, 0.0991, 2.1749, 0.4097, 0.0985, 0.0471])   # Table 5.3, N·m²


def rfma(scaffolds: int, seed: int, path: str | None):
    if path:
        from proprio.systems.trajectories import load_trajectory
        return load_trajectory(path)[0]
    from proprio.systems.rfma import generate_rfma, load_rfma_config
    return generate_rfma(load_rfma_config(scaffolds=scaffolds, seed=seed))[1].trajectory


def coupled_drive(seed: int, seconds: float = 10.0) -> None:
    """Real-time factor by CPU of the coupled-drive twin (``staubli_tx40_twin``) on a smooth seeded path of
    ``seconds`` [s] (knots every 1 s, ±0.4 rad around mid-range), beside the same twin with its coupling dropped."""
    import dataclasses

    from pydrake.trajectories import PiecewisePolynomial

    config = load_twin_config("staubli_tx40_twin")
    desc = config.robot
    knots = (desc.lower + desc.upper) / 2 + np.random.default_rng(seed).uniform(-0.4, 0.4, (int(seconds) + 1, desc.n))
    traj = PiecewisePolynomial.CubicShapePreserving(np.arange(knots.shape[0], dtype=float), knots.T, True)
    print(f"coupled-drive twin {config.name}: {seconds:.0f} s path at a {config.time_step * 1e3:g} ms step; load "
          f"average at start {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    rows = {}
    for label, cfg in (("coupled drive (CᵀI_aC implicit)", config),
                       ("reference: coupling dropped", dataclasses.replace(config, motor_coupling=None))):
        rec = simulate_twin(cfg, traj, progress=False)
        rows[label] = rec.duration / rec.meta["sim_cpu_s"]
        step_us = rec.meta["sim_cpu_s"] / rec.duration * config.time_step * 1e6
        print(f"  {label:34} {rows[label]:6.2f}x real time by CPU ({step_us:.1f} us per step)")
    coupled, reference = rows.values()
    print(f"  coupled / reference: {coupled / reference:.2f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--twin", default="iiwa14_twin")
    ap.add_argument("--scaffolds", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--trajectory", default=None)
    ap.add_argument("--coupled", action="store_true", help="only the coupled-drive twin's real-time factor")
    args = ap.parse_args()
    if args.coupled:
        return coupled_drive(args.seed)

    traj = rfma(args.scaffolds, args.seed, args.trajectory)
    config = load_twin_config(args.twin)
    load = os.getloadavg()[0]

    def dynamics_only() -> tuple[float, float]:
        sim = start_simulator(build_twin_diagram(config, traj, measurement_chain=False), traj)
        t0, c0 = time.perf_counter(), time.process_time()
        sim.AdvanceTo(traj.end_time())
        return time.process_time() - c0, time.perf_counter() - t0

    dyn = [dynamics_only()]
    t0, c0 = time.perf_counter(), time.process_time()
    rec = simulate_twin(config, traj, progress=sys.stderr.isatty())
    total, cpu = time.perf_counter() - t0, time.process_time() - c0
    dyn.append(dynamics_only())
    sim_s = traj.end_time()
    how = f"measured on a {sim_s:.0f} s path, extrapolated linearly" if sim_s < 3000 else "measured"
    print(f"\ntwin {config.name}: effects {sorted(rec.meta['effects'])}; load average {load:.1f} at start, "
          f"{os.getloadavg()[0]:.1f} at end, on {os.cpu_count()} cores")
    print(f"simulated {sim_s:.1f} s at 1 kHz ({rec.n_samples} samples logged at {rec.rate_hz:g} Hz)")
    dyn_cpu, dyn_wall = (float(np.mean([d[k] for d in dyn])) for k in (0, 1))
    rows = [("dynamics-only Diagram (mean of before/after)", dyn_cpu, dyn_wall),
            ("whole twin: simulation loop", rec.meta["sim_cpu_s"], rec.meta["sim_wall_s"]),
            ("whole twin: simulate_twin end to end", cpu, total)]
    print(f"{'':46}{'CPU s':>8}{'x real time':>13}{'us/step':>9}{'wall s':>8}{'x real time':>13}")
    for label, c, w in rows:
        print(f"{label:46}{c:8.2f}{sim_s / c:13.1f}{c / sim_s * 1e3:9.1f}{w:8.2f}{sim_s / w:13.1f}")
    print(f"  dynamics-only runs (CPU s): {', '.join(f'{d[0]:.2f}' for d in dyn)}")
    print(f"whole twin end to end / dynamics-only, by CPU: {dyn_cpu / cpu:.2f}x (target >= 0.65); "
          f"{sim_s / cpu:.1f}x real time (target >= 15)")
    print(f"projected time for the 3600 s RFMA path ({how}): {3600 * total / sim_s / 60:.1f} min wall now, "
          f"{3600 * cpu / sim_s / 60:.1f} min on one free core")

    desc = config.robot
    fric = config.effect("viscous_coulomb")
    q_true, qd, qdd, batch = rec.truth["q_true"], rec.truth["qd"], rec.truth["qdd"], 100_000   # exact motion (truth)
    tau_rbd = np.concatenate([inverse_dynamics(desc, q_true[i:i + batch], qd[i:i + batch], qdd[i:i + batch])
                              for i in range(0, rec.n_samples, batch)])
    tau_model = tau_rbd + fric.friction(qd)                     # the twin's own law (proprio.friction_law)
    mse_raw = np.mean((rec.tau - tau_model) ** 2, axis=0)
    mse_clean = np.mean((rec.tau - rec.truth["tau_torque_noise"] - tau_model) ** 2, axis=0)
    print("\nper-joint MSE [N·m²] of the identified-style RBD model (true inertials + viscous/Coulomb) on twin data")
    header = "".join(f"{'joint ' + str(j + 1):>9}" for j in range(desc.n))
    print(f"{'':28}{header}{'mean':>9}")
    for label, row in (("twin, raw tau", mse_raw), ("twin, white noise removed", mse_clean),
                       ("thesis Table 5.3 RBD (test)", THESIS_RBD_TEST_MSE)):
        print(f"{label:28}" + "".join(f"{v:9.3f}" for v in row) + f"{row.mean():9.3f}")
    print(f"{'twin RMS [N·m], raw tau':28}" + "".join(f"{v:9.3f}" for v in np.sqrt(mse_raw))
          + "   (real LWR 4+ vs its nominal model: 0.27-1.55 N·m RMS, DESIGN.md)")


if __name__ == "__main__":
    main()
