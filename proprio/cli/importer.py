"""``proprio import MAPPING --out REC.npz``: convert a robot's own log files (CSV/TXT) into a Recording; the work is
done by :mod:`proprio.importer`."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from proprio.cli import add_chain_args, load_robot_arg

__all__ = ["register"]


def _import(args: argparse.Namespace) -> int:
    from proprio.importer import import_recording, load_mapping
    from proprio.recording import save_recording, validate_recording

    out = Path(args.out)
    if out.suffix != ".npz":
        raise ValueError(f"--out {out}: a Recording file must end in .npz")
    if out.is_dir():
        raise ValueError(f"--out {out}: is a directory")
    if (args.base or args.tip) and not args.robot:
        raise ValueError("--base/--tip select the chain of the --robot URDF: give --robot too")
    mapping = load_mapping(args.mapping)
    rec = import_recording(mapping, data_dir=args.data_dir, robot_name=args.robot)
    if args.robot:
        validate_recording(rec, load_robot_arg(args.robot, args), source=str(args.mapping))   # joint count and limits
    save_recording(rec, out)
    print(f"wrote {out}: {rec.n_samples} samples, {rec.duration:.3f} s at {rec.rate_hz:.6g} Hz, {rec.n_joints} "
          f"joints, tau_kind {rec.meta['tau_kind']}")
    with np.printoptions(precision=3, suppress=True, linewidth=120):
        print(f"  q range [rad]: min {rec.q.min(axis=0)}  max {rec.q.max(axis=0)}")
        print(f"  max |tau| [N·m]: {np.abs(rec.tau).max(axis=0)}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "import", help="convert CSV/TXT robot logs into a Recording (.npz) with a mapping YAML",
        description="Read a robot's own log files (one table or one file per channel; with or without header; any "
                    "delimiter; decimal point or comma) as a mapping YAML (format proprio-import/v1) says: which "
                    "columns are t, q, q̇, τ or motor current, their units (rad, deg, counts), gear ratios, torque "
                    "constants and the motor↔joint coupling (q = R⁻¹ q_motor, τ = Rᵀ τ_motor), encoder zero "
                    "offsets, the rate when there is no time column, and whether τ is a link-side sensor torque or "
                    "a drive torque (meta.tau_kind). Example: proprio/configs/import_tx40.yaml.")
    p.add_argument("mapping", type=Path, help="mapping YAML (format proprio-import/v1)")
    p.add_argument("--out", required=True, help="output Recording (.npz)")
    p.add_argument("--data-dir", type=Path, default=None,
                   help="folder the mapping's file names are relative to (default: the mapping's folder)")
    p.add_argument("--robot", default=None, help="robot description to record in meta.robot and to validate the "
                                                 "joint count and limits against (default: the mapping's 'robot')")
    add_chain_args(p)
    p.set_defaults(func=_import)
