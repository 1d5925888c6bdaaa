"""``proprio demo``: run every pipeline stage on the built-in default (see :mod:`proprio.demo`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from proprio.cli import check_output
from proprio.demo import DEFAULT_OUT, FULL, QUICK, run_demo


def run(args: argparse.Namespace) -> int:
    check_output(args.out, "--out", "dir")
    run_demo(args.out, size=QUICK if args.quick else FULL)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo", help="run the whole pipeline on the built-in default and write its outputs",
        description="Run every pipeline stage on the built-in default, the calibrated iiwa 14 twin: an RFMA "
                    "trajectory, the twin simulated in Drake, identification on the optimal excitation, the payload "
                    "experiment with both wrench observers, the gap diagnosis against the nominal CAD model and a "
                    "hybrid residual network. Prints where each output is (about 2.5 min on 2 idle cores).")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default {DEFAULT_OUT}/)")
    p.add_argument("--quick", action="store_true",
                   help=f"every stage on reduced sizes ({QUICK.twin_seconds:g} s of twin, {QUICK.hybrid_epochs} "
                        "epochs, ...): a check that the pipeline runs, not its numbers")
    p.set_defaults(func=run)
