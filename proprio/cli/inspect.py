"""``proprio inspect FILE``: a summary table of a Recording (or a real LWR 4+ file), its data-quality findings and an
optional PNG plot; the work is done by :mod:`proprio.inspection` and :mod:`proprio.data_quality`."""
from __future__ import annotations

import argparse
from pathlib import Path

from proprio.data_quality import assess, format_findings
from proprio.description import load_robot
from proprio.inspection import DEFAULT_DEADBAND, format_summary, load_any, plot_recording, summarize_recording
from proprio.cli import check_output, check_recording_robot, nonnegative

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    check_output(args.plot, "--plot", "file")
    robot = load_robot(args.robot) if args.robot else None
    rec = load_any(args.file, robot=robot, angle_unit=args.angle_unit)
    if robot is not None:
        rec = check_recording_robot(rec, robot, args.file, "--robot")
    summary = summarize_recording(rec, robot, deadband=args.deadband)
    print(format_summary(summary, title=str(args.file)))
    print("\n" + format_findings(assess(rec, robot), title="data quality (most severe first)"))
    if args.plot:
        print(f"\nplot: {plot_recording(rec, args.plot, robot, title=Path(args.file).name)}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "inspect", help="summarise a Recording (.npz, incl. the real LWR 4+ files) and optionally plot it",
        description="Validate a Recording and print duration, rate, sample count and, per joint, the position range "
                    "(rad and deg), max |q̇|, RMS τ and direction reversals per second, then the data-quality "
                    "findings (time-stamp jitter and gaps, duplicates, clipping, quantisation, τ filtered upstream, "
                    "q̇ vs dq/dt, q̈ noise) and the signal-conditioning line. Corrupted files (truncated, "
                    "NaN/inf, non-increasing time, degrees, joint count or limits mismatch with --robot) give a "
                    "one-line error and exit code 2.")
    p.add_argument("file", type=Path, help="Recording .npz (proprio format or a FloBaRoID LWR 4+ measurements file) "
                                           "or a .csv with columns t, q1..qn, tau1..taun[, qd1.., qdd1.., fx..mz]")
    p.add_argument("--angle-unit", choices=("rad", "deg"), default="rad",
                   help="unit of the angles in a .csv file (default rad; .npz files are always rad)")
    p.add_argument("--robot", help="robot to validate against and name joints by: a built-in name "
                                   "(iiwa14_identified, iiwa14_nominal), a YAML/URDF file or a directory with "
                                   "robot.yaml")
    p.add_argument("--plot", type=Path, metavar="PNG", help="write a PNG of q and τ over time to this path")
    p.add_argument("--deadband", type=nonnegative, default=DEFAULT_DEADBAND,
                   help=f"q̇ deadband for reversal counting [rad/s] (default {DEFAULT_DEADBAND})")
    p.set_defaults(func=run)
