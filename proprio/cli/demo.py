"""``proprio demo``: run every pipeline stage on the built-in default (see :mod:`proprio.demo`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from proprio.demo import DEFAULT_OUT, run_demo


def run(args: argparse.Namespace) -> int:
    run_demo(args.out)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo", help="run the whole pipeline on the built-in default and write its outputs",
        description="Run every pipeline stage on the built-in default robot (iiwa14_identified): build and simulate "
                    "the twin in Drake, save a Recording, summarise and plot it (later stages: identification, "
                    "observers, diagnosis). Prints where each output is.")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default {DEFAULT_OUT}/)")
    p.set_defaults(func=run)
