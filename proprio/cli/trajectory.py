"""``proprio trajectory``: generate RFMA trajectories (§4.3) and plot them as in the thesis' Fig. 4.9."""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import yaml

from proprio.cli import UserError, check_output, nonnegative_int, positive, positive_int
from proprio.description import load_robot

__all__ = ["register"]


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("trajectory", help="generate and plot joint trajectories (RFMA, thesis §4.3)",
                              description="Generate and plot joint trajectories.")
    sub = p.add_subparsers(dest="trajectory_command", metavar="SUBCOMMAND")

    r = sub.add_parser("rfma", help="random fine-motion trajectory (Algorithm 4.10) → .npz",
                       description="Generate an RFMA trajectory: collision-free scaffolds in the quarter-sphere "
                                   "workspace, nearest-neighbour ordered, each followed by a random sinusoidal "
                                   "exploration; time-parameterised within the robot's velocity/acceleration "
                                   "limits and saved as a piecewise-cubic .npz (load with "
                                   "proprio.systems.trajectories.load_trajectory).")
    r.add_argument("--scaffolds", type=positive_int, default=None, help="number of scaffolds L (default: config, 150)")
    r.add_argument("--seed", type=nonnegative_int, default=None, help="random seed (default: config)")
    r.add_argument("--config", type=Path, default=None, help="RFMA YAML config (default: proprio/configs/rfma.yaml)")
    r.add_argument("--robot", default=None, help="robot name or description file (default: config)")
    r.add_argument("--out", type=Path, required=True, help="output trajectory file (.npz)")
    r.set_defaults(func=_cmd_rfma)

    pl = sub.add_parser("plot", help="plot a trajectory file (flange path coloured by speed; joint angles)",
                        description="Plot a trajectory .npz as in the thesis' Fig. 4.9: the flange path in 3-D "
                                    "coloured by its linear speed (top) and the joint angles over time (bottom).")
    pl.add_argument("file", type=Path, help="trajectory .npz written by 'proprio trajectory rfma'")
    pl.add_argument("--out", type=Path, default=None, help="output PNG (default: FILE with .png)")
    pl.add_argument("--robot", default=None, help="robot for the forward kinematics (default: the file's robot)")
    pl.add_argument("--rate", type=positive, default=50.0, help="plot sample rate [Hz] (default 50)")
    pl.set_defaults(func=_cmd_plot)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _cmd_rfma(args: argparse.Namespace) -> int:
    from proprio.systems.rfma import generate_rfma, load_rfma_config, trajectory_meta
    from proprio.systems.trajectories import save_trajectory

    check_output(args.out, "--out", "file")
    overrides = {k: v for k, v in (("scaffolds", args.scaffolds), ("seed", args.seed), ("robot", args.robot))
                 if v is not None}
    try:
        cfg = load_rfma_config(args.config, **overrides)
    except yaml.YAMLError as exc:
        raise UserError(f"--config {args.config}: not valid YAML ({exc})") from None
    desc = load_robot(cfg.robot)
    t0 = time.perf_counter()
    path, timed = generate_rfma(cfg, desc, progress=True)
    out = save_trajectory(args.out, timed.trajectory, trajectory_meta(path, timed, cfg, desc))
    print(f"wrote {out}: {path.n_scaffolds} scaffolds, {path.waypoints.shape[0]} waypoints, "
          f"{timed.duration:.1f} s of motion ({time.perf_counter() - t0:.1f} s to generate, {path.tries} "
          "scaffold candidates drawn)")
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from proprio.systems.rfma import plot_trajectory
    from proprio.systems.trajectories import load_trajectory

    check_output(args.out, "--out", "file")
    traj, meta = load_trajectory(args.file)
    robot = args.robot or meta.get("robot")
    if robot is None:
        raise UserError(f"{args.file}: no 'robot' in its metadata; pass --robot")
    desc = load_robot(robot)
    if traj.rows() != desc.n:
        raise UserError(f"{args.file}: trajectory has {traj.rows()} joints but robot '{desc.name}' has {desc.n}")
    if not args.rate > 0:
        raise UserError(f"--rate must be > 0, got {args.rate}")
    out = args.out or args.file.with_suffix(".png")
    plot_trajectory(traj, desc, out, rate_hz=args.rate, title=f"{args.file.name}: flange path coloured by speed")
    print(f"wrote {out}")
    return 0
