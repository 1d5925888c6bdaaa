"""``proprio identify`` (rigid-body backbone from recordings) and ``proprio excite`` (optimal excitation design)."""
from __future__ import annotations

import argparse
import json

import numpy as np
from proprio.cli import (UserError, add_chain_args, check_output, check_recording_robot, load_robot_arg, nonnegative,
                         nonnegative_int, positive_int)
from proprio.cli.flags import add_cutoff_hz, add_list, add_split, add_trim, conditioning_of, split_tails


__all__ = ["register"]


def _identify(args: argparse.Namespace) -> int:
    import dataclasses

    from proprio.data_quality import assess, format_findings
    from proprio.identification.estimators import torque_error_table
    from proprio.identification.model_io import save_model
    from proprio.identification.recordings import (TRIM_S, check_tau_kind, identify_recordings, piece_torque, pieces,
                                                   stack_recordings)
    from proprio.identification.regressor import drive_identified
    from proprio.recording import load_recording

    check_output(args.out, "--out", "file")
    robot = load_robot_arg(args.robot, args)
    if args.sensor_terms and drive_identified(robot):
        raise UserError(f"--sensor-terms: the robot description {robot.name!r} says τ is a drive torque "
                        "(drive.tau_kind: drive); the sensor terms are a link-side torque sensor's — leave the flag "
                        "out")
    train = [check_recording_robot(load_recording(p, robot), robot, p, "--robot") for p in args.train]
    validate = [check_recording_robot(load_recording(p, robot), robot, p, "--robot") for p in args.validate]
    check_tau_kind(train + validate, args.train + args.validate, robot)
    trim_s = TRIM_S if args.trim is None else args.trim
    train, tails, tail_names = split_tails(args, train, args.train)     # held-out tail of every training recording
    validate, val_names = validate + tails, list(args.validate) + tail_names
    if tails:
        head = (f"{args.split_at:g} s" if args.split_at is not None else f"{100 * (1 - args.holdout_fraction):.3g} %")
        print(f"split: train on the first {head} of each --train recording, validate on the rest: "
              + ", ".join(tail_names))
    if args.no_drive and robot.drive is not None:
        robot = dataclasses.replace(robot, drive=None)
    conditioning = conditioning_of(args)
    offsets = args.offsets or drive_identified(robot)
    load_friction = args.load_friction or robot.friction_load_dependent     # the flag or the description asks
    for role, paths, recs in (("train", args.train, train), ("validate", val_names, validate)):
        for path, rec in zip(paths, recs):          # warnings and problems only, and the conditioning line (once)
            print(format_findings(assess(rec, robot, conditioning=conditioning), "warning",
                                  title=f"data quality of {path} ({role}):"))
    sensor = None
    if args.sensor_terms:
        from proprio.identification.sensor_terms import SensorTermSettings
        sensor = SensorTermSettings.defaults(robot.n, robot.drive.gear_ratio if robot.drive is not None else None)
    model, text = identify_recordings(train, [], robot, args.method, trim_s, offsets,
                                      args.coulomb_velocity_scale, conditioning, load_friction=load_friction,
                                      sensor=sensor)
    print(f"{args.method.upper()} on {model.n_train_samples} samples: {model.phi_b.size} parameters "
          f"({model.base.n_base} base{' incl. drive terms' if drive_identified(robot) else ''}"
          f"{' + offsets' if offsets else ''}{_load_friction_note(args.load_friction, robot.friction_load_dependent)}"
          f"{' + sensor terms (' + ', '.join(sensor.terms) + ')' if sensor is not None else ''})")
    if sensor is not None and sensor.gear_ratio is None:
        print("sensor terms: no ripple (the robot description gives no gear ratios: drive.gear_ratio)")
    if args.show_parameters:
        print(model.parameter_table())
    print(text.split("\n\n", 1)[1])                # the tables: their conditioning lines were printed above
    for path, rec in zip(val_names, validate):      # one table per held-out file: runs are not pooled
        (q, qd, qdd, tau), _ = stack_recordings([rec], trim_s, conditioning)
        print("\n" + torque_error_table(tau, model.torque(q, qd, qdd), f"validation: {path}")[0])
    stacked, cond_tr = stack_recordings(train, trim_s, conditioning)
    e_train = stacked[3] - piece_torque(model, *stacked[:3], pieces(cond_tr, trim_s))   # per recording, as fitted
    for line in _advice(model, e_train, args.method, offsets):
        print(line)
    save_model(model, args.out)
    print(f"wrote {args.out}")
    return 0


def _load_friction_note(flag: bool, described: bool) -> str:
    """The parameter count's words for the load gains and who asked for them (the flag, the description, or both:
    either turns them on)."""
    if not (flag or described):
        return ""
    who = " and ".join(w for w, on in (("--load-friction", flag), ("the description's friction.load_dependent",
                                                                     described)) if on)
    return f" + load-dependent friction gains ({who})"


OFFSET_ALPHA = 0.01
"""Significance level of identify's test for a constant part in the residual (two-sided, over all joints)."""


def _advice(model, e: np.ndarray, method: str, offsets: bool) -> list[str]:
    """What identify can tell beyond its tables: an OLS/WLS model that is not physically consistent (suggest
    ``--method sdp``), and a training residual ``e [N,n]`` [N·m] (each recording's from its own start, as fitted)
    with a constant part beyond its noise (suggest ``--offsets``): per joint the mean against its standard error,
    ``t = |ē| / (σ √(f / N))`` with ``f`` the residual's autocorrelation factor N/N_eff
    (:func:`proprio.diagnosis.selection.block_test.n_eff_factor`), named where ``t`` exceeds the two-sided
    :data:`OFFSET_ALPHA` level Bonferroni-corrected over the joints."""
    from scipy.stats import norm

    from proprio.diagnosis.selection.block_test import n_eff_factor
    from proprio.identification.estimators import inconsistent_links

    lines = []
    bad = inconsistent_links(model) if method != "sdp" else []
    if bad:
        lines.append(f"advice: the {method.upper()} model is not physically consistent (the link inertia or friction "
                     f"of joint(s) {', '.join(map(str, bad))}): Drake warns when it builds a plant from it (view, "
                     "estimate, train); --method sdp identifies a physically consistent model")
    if not offsets:
        mean, sd = e.mean(axis=0), np.maximum(e.std(axis=0), 1e-12)
        factor = np.array([n_eff_factor(e[:, [j]]) for j in range(e.shape[1])])
        t = np.abs(mean) / (sd * np.sqrt(factor / e.shape[0]))
        level = float(norm.isf(OFFSET_ALPHA / (2 * e.shape[1])))
        hit = np.flatnonzero(t > level)
        if hit.size:
            said = ", ".join(f"joint {j + 1}: mean {mean[j]:+.3g} N·m, σ {sd[j]:.3g} N·m, t = {t[j]:.1f}" for j in hit)
            lines.append(f"advice: the training residual has a constant part beyond its noise ({said}; t > "
                         f"{level:.2f} is the {100 * OFFSET_ALPHA:g} % level over the joints, autocorrelation "
                         "counted): --offsets fits a constant torque offset per joint")
    return lines


def _excite(args: argparse.Namespace) -> int:
    from proprio.description import load_robot
    from proprio.identification.excitation import (
        check_collisions, load_excitation_config, optimise_excitation, protocol_trajectory)
    from proprio.io import atomic_path

    check_output(args.out, "--out", "file")
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
    period_t = np.arange(0.0, result.trajectory.period, 1.0 / cfg.collision.check_rate_hz)
    hits = check_collisions(robot, result.trajectory.evaluate(period_t)[0])
    if hits:
        k, a, b = hits[0]
        print(f"WARNING: {len(hits)} self-collision samples, first at t = {period_t[k]:.2f} s ({a} / {b})")
    else:
        print(f"collision check: free ({period_t.size} samples)")
    pr = cfg.protocol
    t, q, qd, qdd = protocol_trajectory(result.trajectory, list(pr.speed_factors), pr.rate_hz)
    meta = {"robot": robot.name, "cond": result.cond, "start_conds": result.start_conds, "solver": result.solver,
            "repetitions": pr.repetitions, "speed_factors": list(pr.speed_factors), "collisions": len(hits),
            "config": cfg.to_dict()}
    with atomic_path(args.out, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, t=t, q=q, qd=qd, qdd=qdd, a=result.trajectory.a, b=result.trajectory.b,
                     omega_f=result.trajectory.omega_f, meta=np.array(json.dumps(meta)))
    print(f"wrote {args.out}: {t.size} samples, {t[-1]:.1f} s per repetition × {pr.repetitions}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "identify", help="identify the rigid-body backbone (base parameters) from recordings",
        description="Identify base inertial + friction parameters (thesis §4.1) by OLS, weighted LS or a "
                    "physically consistent SDP; print Table 4.4-style per-joint errors on the training data and "
                    "on each validation file (one table per file) and save the model (.npz).")
    p.add_argument("--robot", required=True, help="robot description: built-in name, YAML, URDF or directory "
                                                  "(kinematics + a-priori inertials)")
    add_chain_args(p)
    add_list(p, "--train", required=True, metavar="REC",
             help="training recordings (.npz; FloBaRoID LWR files accepted)")
    add_list(p, "--validate", nargs="*", default=[], metavar="REC",
             help="validation recordings (one error table per file)")
    p.add_argument("--method", choices=("ols", "wls", "sdp"), default="ols", help="estimator (default ols)")
    p.add_argument("--out", required=True, help="output model file (.npz)")
    add_trim(p, None, "0.5, as diagnose: proprio.identification.recordings.TRIM_S")
    p.add_argument("--offsets", action="store_true", help="also fit a constant torque offset per joint (always on "
                                                          "for a drive-torque arm)")
    p.add_argument("--no-drive", action="store_true",
                   help="leave out the drive columns (rotor inertia, coupled motor friction) of a robot whose "
                        "description has drive.tau_kind: drive — the ablation of the same identification")
    add_split(p, None, "none: validate on --validate only; the held-out ends are added to it")
    add_cutoff_hz(p)
    p.add_argument("--coulomb-velocity-scale", type=nonnegative, default=None,
                   help="[rad/s] Coulomb friction as tanh(qd/scale); 0 = sign(qd) (default: the library's smoothing, "
                        "proprio.friction_law.SMOOTH_VELOCITY = 0.05)")
    p.add_argument("--load-friction", action="store_true",
                   help="also fit load-dependent Coulomb friction per joint: F_c = F_c0 + k |tau| (k [-] per joint, "
                        "the measured link torque as the load); on anyway when the robot description says "
                        "friction: {load_dependent: true}")
    p.add_argument("--sensor-terms", action="store_true",
                   help="also fit the torque sensor's laws per joint (a link-side sensor): its gain error, "
                        "hysteresis and lost motion (each a level [N m] and a load gain [-], the a-priori model's "
                        "|tau| as the load; the twin's laws at their default travel scales) and, where the robot "
                        "description gives gear ratios, the ripple (sin/cos of harmonic x gear ratio x q); the model "
                        "carries their reversal state online")
    p.add_argument("--show-parameters", action="store_true", help="print the base-parameter table (Table 4.6)")
    p.set_defaults(func=_identify)

    e = subparsers.add_parser(
        "excite", help="design an optimal Fourier excitation trajectory (min cond(K_b))",
        description="Optimise a finite Fourier series trajectory (L = 5, w_f = 0.1 pi, thesis eq. 4.9-4.19) for "
                    "cond(K_b) with SNOPT from several random starts, check it for self-collisions and write the "
                    "§4.1 protocol (period concatenated at decreasing speed) as an .npz with t, q, qd, qdd.")
    e.add_argument("--robot", default="iiwa14_nominal", help="robot description (default iiwa14_nominal)")
    e.add_argument("--out", required=True, help="output trajectory file (.npz)")
    e.add_argument("--starts", type=positive_int, default=None, help="number of random starts (config default 4)")
    e.add_argument("--seed", type=nonnegative_int, default=None, help="random seed of the starts (config default 0)")
    e.set_defaults(func=_excite)
