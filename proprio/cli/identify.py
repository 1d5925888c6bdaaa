"""``proprio identify`` (rigid-body backbone from recordings) and ``proprio excite`` (optimal excitation design)."""
from __future__ import annotations

import argparse
import json

import numpy as np


__all__ = ["register"]


def _identify(args: argparse.Namespace) -> int:
    from proprio.data_quality import assess, format_findings
    from proprio.description import load_robot
    from proprio.identification.model_io import save_model
    from proprio.identification.estimators import torque_error_table
    from proprio.identification.recordings import identify_recordings, stack_recordings
    from proprio.recording import load_recording

    robot = load_robot(args.robot)
    train = [load_recording(p, robot) for p in args.train]
    validate = [load_recording(p, robot) for p in args.validate]
    for role, paths, recs in (("train", args.train, train), ("validate", args.validate, validate)):
        for path, rec in zip(paths, recs):          # warnings and problems only, and the conditioning line
            print(format_findings(assess(rec, robot), "warning", title=f"data quality of {path} ({role}):"))
    model, text = identify_recordings(train, [], robot, args.method, args.trim, args.offsets,
                                      args.coulomb_velocity_scale)
    print(f"{args.method.upper()} on {model.n_train_samples} samples: {model.phi_b.size} parameters "
          f"({model.base.n_base} base{' + offsets' if args.offsets else ''})")
    if args.show_parameters:
        print(model.parameter_table())
    print(text)
    for path, rec in zip(args.validate, validate):   # one table per held-out file: runs are not pooled
        (q, qd, qdd, tau), (cs,) = stack_recordings([rec], args.trim)
        print(f"\n{cs.describe()}\n" + torque_error_table(tau, model.torque(q, qd, qdd), f"validation: {path}")[0])
    save_model(model, args.out)
    print(f"wrote {args.out}")
    return 0


def _excite(args: argparse.Namespace) -> int:
    from proprio.description import load_robot
    from proprio.identification.excitation import (
        check_collisions, load_excitation_config, optimise_excitation, protocol_trajectory)
    from proprio.io import atomic_path

    robot = load_robot(args.robot)
    overrides: dict = {}
    if args.starts is not None:
        overrides.setdefault("optimisation", {})["starts"] = args.starts
    if args.seed is not None:
        overrides.setdefault("optimisation", {})["seed"] = args.seed
    cfg = load_excitation_config(overrides)
    result = optimise_excitation(robot, cfg, progress=True)
    print(f"cond(K_b) = {result.cond:.1f} (thesis: 68); per start: "
          + ", ".join(f"{c:.1f}" for c in result.start_conds))
    period_t = np.arange(0.0, result.trajectory.period, 1.0 / cfg["collision"]["check_rate_hz"])
    hits = check_collisions(robot, result.trajectory.evaluate(period_t)[0])
    if hits:
        k, a, b = hits[0]
        print(f"WARNING: {len(hits)} self-collision samples, first at t = {period_t[k]:.2f} s ({a} / {b})")
    else:
        print(f"collision check: free ({period_t.size} samples)")
    pr = cfg["protocol"]
    t, q, qd, qdd = protocol_trajectory(result.trajectory, pr["speed_factors"], pr["rate_hz"])
    meta = {"robot": robot.name, "cond": result.cond, "start_conds": result.start_conds, "solver": result.solver,
            "repetitions": pr["repetitions"], "speed_factors": pr["speed_factors"], "collisions": len(hits),
            "config": cfg}
    with atomic_path(args.out, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, t=t, q=q, qd=qd, qdd=qdd, a=result.trajectory.a, b=result.trajectory.b,
                     omega_f=result.trajectory.omega_f, meta=np.array(json.dumps(meta)))
    print(f"wrote {args.out}: {t.size} samples, {t[-1]:.1f} s per repetition × {pr['repetitions']}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "identify", help="identify the rigid-body backbone (base parameters) from recordings",
        description="Identify base inertial + friction parameters (thesis §4.1) by OLS, weighted LS or a "
                    "physically consistent SDP; print Table 4.4-style per-joint errors on the training data and "
                    "on each validation file (one table per file) and save the model (.npz).")
    p.add_argument("--robot", required=True, help="robot description: built-in name, YAML, URDF or directory "
                                                  "(kinematics + a-priori inertials)")
    p.add_argument("--train", nargs="+", required=True, metavar="REC", help="training recordings (.npz; FloBaRoID "
                                                                            "LWR files accepted)")
    p.add_argument("--validate", nargs="*", default=[], metavar="REC",
                   help="validation recordings (one error table per file)")
    p.add_argument("--method", choices=("ols", "wls", "sdp"), default="ols", help="estimator (default ols)")
    p.add_argument("--out", required=True, help="output model file (.npz)")
    p.add_argument("--trim", type=int, default=100, help="samples dropped at both ends of every recording "
                                                         "(filter start-up; default 100)")
    p.add_argument("--offsets", action="store_true", help="also fit a constant torque offset per joint")
    p.add_argument("--coulomb-velocity-scale", type=float, default=0.02,
                   help="[rad/s] Coulomb friction as tanh(qd/scale); 0 = sign(qd) (default 0.02)")
    p.add_argument("--show-parameters", action="store_true", help="print the base-parameter table (Table 4.6)")
    p.set_defaults(func=_identify)

    e = subparsers.add_parser(
        "excite", help="design an optimal Fourier excitation trajectory (min cond(K_b))",
        description="Optimise a finite Fourier series trajectory (L = 5, w_f = 0.1 pi, thesis eq. 4.9-4.19) for "
                    "cond(K_b) with SNOPT from several random starts, check it for self-collisions and write the "
                    "§4.1 protocol (period concatenated at decreasing speed) as an .npz with t, q, qd, qdd.")
    e.add_argument("--robot", default="iiwa14_nominal", help="robot description (default iiwa14_nominal)")
    e.add_argument("--out", required=True, help="output trajectory file (.npz)")
    e.add_argument("--starts", type=int, default=None, help="number of random starts (config default 4)")
    e.add_argument("--seed", type=int, default=None, help="random seed of the starts (config default 0)")
    e.set_defaults(func=_excite)
