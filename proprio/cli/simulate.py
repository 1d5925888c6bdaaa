"""``proprio simulate`` (run the twin along a trajectory — a base twin with a diagnosis' ``--patch`` merged in, or
``--replay`` of a measured recording with the gap through the twin) and ``proprio twin hysteresis-test`` (thesis
Fig. 2.5)."""
from __future__ import annotations

import argparse
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from proprio.cli import UserError, add_chain_args, add_plugin_args, check_output, check_recording_robot, finite, nonnegative, nonnegative_int, positive
from proprio.cli.flags import add_quiet, add_trim, add_twin

if TYPE_CHECKING:
    from proprio.diagrams.twin import TwinConfig

__all__ = ["register", "load_any_trajectory"]


def load_any_trajectory(path: str | Path):
    """A trajectory file for the twin: a ``proprio trajectory`` file (``breaks, q, qd, meta``), or a Recording
    ``.npz`` whose q(t) is replayed (shape-preserving cubic through the samples)."""
    from proprio.recording import LWR4_KEYS, load_recording
    from proprio.systems.trajectories import load_trajectory, replay_trajectory

    path = Path(path)
    if not path.exists():
        raise UserError(f"--trajectory: no such file: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise UserError(f"--trajectory: {path} is not a readable .npz, truncated or corrupted ({exc})") from None
    if {"breaks", "q", "qd"} <= keys:
        return load_trajectory(path)[0]
    if {"t", "q"} <= keys or LWR4_KEYS <= keys:
        return replay_trajectory(load_recording(path), interpolation="cubic")
    raise UserError(f"--trajectory: {path} is neither a proprio trajectory (breaks, q, qd) nor a Recording (t, q, tau)")


def _replay(args: argparse.Namespace, config: "TwinConfig", base: "TwinConfig | None") -> int:
    """``simulate --replay REC``: the held-out recording replayed through the (patched) twin without noise."""
    from proprio.diagnosis.data import DiagnosisError
    from proprio.diagnosis.replay import replay_gap
    from proprio.diagrams.twin import TwinConfigError
    from proprio.recording import RecordingError, load_recording, save_recording

    path = Path(args.replay)
    if not path.exists():
        raise UserError(f"--replay: no such file: {path}")
    try:
        rec = check_recording_robot(load_recording(path, config.robot), config.robot, path, "--twin", twin=True)
        gap = replay_gap(config, [rec], base=base, trim_s=args.trim, progress=not args.quiet)
    except (RecordingError, DiagnosisError, TwinConfigError) as exc:
        raise UserError(f"--replay {path}: {exc}") from exc
    save_recording(gap.recordings[0], args.out)
    print(f"replayed {path} ({rec.duration:.1f} s) through {config.name} (no twin noise) -> {args.out}")
    segments = gap.recordings[0].meta.get("segments_s", [])
    if len(segments) > 1:
        print(f"the log has gaps: {len(segments)} measured stretches replayed one by one, nothing in between ("
              + ", ".join(f"{a:.3f}–{b:.3f} s" for a, b in segments) + ")")
    print(gap.text())
    print(gap.table())
    return 0


def _simulate(args: argparse.Namespace) -> int:
    import time

    from proprio.diagrams.twin import TwinConfigError, load_twin_config, simulate_twin
    from proprio.systems.trajectories import truncate_trajectory
    from proprio.payload import Payload
    from proprio.recording import save_recording

    check_output(args.out, "--out", "file")
    if (args.trajectory is None) == (args.replay is None):
        raise UserError("give exactly one of --trajectory (a motion to simulate) and --replay (a recording to replay)")
    try:
        config = load_twin_config(args.twin, patch=args.patch, base_link=args.base, tip_link=args.tip)
        base = load_twin_config(args.twin, base_link=args.base, tip_link=args.tip) if args.patch is not None else None
    except TwinConfigError as exc:
        raise UserError(f"--twin/--patch: {exc}") from exc
    if args.replay is not None:
        extra = [flag for flag, v in (("--payload-kg", args.payload_kg), ("--seconds", args.seconds),
                                      ("--log-rate", args.log_rate), ("--seed", args.seed)) if v is not None]
        if extra:
            raise UserError(f"--replay replays the whole recording through the twin as configured (no noise, every "
                            f"step logged): {', '.join(extra)} do not apply")
        return _replay(args, config, base)
    if args.payload_kg is not None and not (np.isfinite(args.payload_kg) and args.payload_kg >= 0):
        raise UserError(f"--payload-kg must be a finite mass >= 0 kg, got {args.payload_kg}")
    if args.seed is not None:
        config.seed = args.seed
    if args.log_rate is not None:
        try:
            config = config.with_logger(rate_hz=args.log_rate)
        except TwinConfigError as exc:
            raise UserError(f"--log-rate {args.log_rate:g}: {exc}") from exc
    traj = load_any_trajectory(args.trajectory)
    if args.seconds is not None:
        traj = truncate_trajectory(traj, args.seconds)
    payload = None
    if args.payload_kg is not None:
        payload = Payload(args.payload_kg, tuple(args.payload_com)) if args.payload_kg > 0 else None
    wall0 = time.perf_counter()
    rec = simulate_twin(config, traj, payload=payload, progress=not args.quiet)
    save_recording(rec, args.out)
    wall = time.perf_counter() - wall0
    print(f"simulated {rec.duration:.1f} s of {config.name} in {wall:.1f} s wall "
          f"({rec.meta['real_time_factor']:.1f}x real time in the simulator), {rec.n_samples} samples at "
          f"{config.logger.rate_hz:g} Hz ({', '.join(config.logger.channels)}; {rec.meta['samples_lost']} lost) "
          f"-> {args.out}")
    return 0


def _hysteresis_test(args: argparse.Namespace) -> int:
    from proprio.diagrams.twin import load_twin_config, run_hysteresis_test

    check_output(args.out, "--out", "dir")
    config = load_twin_config(args.twin)
    png, rec = run_hysteresis_test(config, args.out, progress=not args.quiet)
    print(f"Fig. 2.5 experiment: {rec.duration:.0f} s simulated -> {png} and {Path(args.out) / 'hysteresis_test.npz'}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "simulate", help="simulate the twin along a trajectory and write a Recording",
        description="Run the twin (plant + joint effects + sensors) along a trajectory and save the Recording "
                    "(.npz) with measured q, tau, truth channels and the true flange wrench. The file is written "
                    "only when the simulation finishes (atomic write). --patch merges a twin_patch.yaml from "
                    "'proprio diagnose' into the twin; --replay re-simulates a measured recording and prints the gap.")
    add_twin(p, "iiwa14_twin", "")
    p.add_argument("--trajectory",
                   help="trajectory .npz from 'proprio trajectory' (breaks, q, qd) or a Recording whose q(t) is "
                        "replayed")
    p.add_argument("--patch", help="twin patch (twin_patch.yaml from 'proprio diagnose') merged into --twin")
    add_chain_args(p)
    p.add_argument("--replay", metavar="REC",
                   help="instead of --trajectory: a measured (held-out) recording whose conditioned q is replayed "
                        "through the twin without its noise; writes the twin's Recording and prints the gap "
                        "RMS(tau_meas - tau_twin) per joint (with --patch: for the base twin and the patched one)")
    add_trim(p, None, "diagnose's: 0.5, at most 5 %% of a recording's length but never less than its low-pass's "
             "settling", what=" with --replay, left out of the gap")
    p.add_argument("--payload-kg", type=nonnegative, default=None,
                   help="payload mass at the flange [kg] (overrides the config's payload)")
    p.add_argument("--payload-com", type=finite, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"),
                   help="payload centre of mass in the flange frame [m] (default 0 0 0)")
    p.add_argument("--seconds", type=positive, default=None, help="simulate only the first SECONDS of the trajectory")
    p.add_argument("--log-rate", type=positive, default=None, help="log rate [Hz] (default: the config's)")
    p.add_argument("--seed", type=nonnegative_int, default=None, help="noise seed (default: the config's)")
    add_quiet(p)
    p.add_argument("--out", required=True, help="output Recording (.npz)")
    add_plugin_args(p)
    p.set_defaults(func=_simulate)

    twin = subparsers.add_parser("twin", help="experiments on the twin (hysteresis-test)",
                                 description="Experiments on the twin.")
    sub = twin.add_subparsers(dest="twin_command", metavar="EXPERIMENT")
    h = sub.add_parser("hysteresis-test", help="thesis Fig. 2.5: tau vs angle, joint-wise ±10° at 10 %% speed",
                       description="Joint-wise triangular motion ±10° around the zero pose at 10 % of each joint's "
                                   "speed limit, one joint after the other; plots measured tau vs angle for the 7 "
                                   "joints with a Savitzky-Golay overlay (hysteresis_test.png) and saves the "
                                   "Recording (hysteresis_test.npz).")
    add_twin(h, "iiwa14_twin", "")
    add_quiet(h)
    h.add_argument("--out", required=True, help="output directory")
    add_plugin_args(h)
    h.set_defaults(func=_hysteresis_test)
