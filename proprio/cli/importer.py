"""``proprio import SOURCE --out REC.npz``: convert a robot's own logs into a Recording — CSV/TXT tables through a
mapping YAML (:mod:`proprio.importer`), or a ROS 1/ROS 2 bag or MCAP file (:mod:`proprio.bag_import`)."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from proprio.cli import add_chain_args, load_robot_arg
from proprio.errors import UserError

__all__ = ["register"]


def _import(args: argparse.Namespace) -> int:
    from proprio.bag_import import import_bag
    from proprio.importer import import_recording, load_mapping
    from proprio.recording import is_bag, save_recording, validate_recording

    out = Path(args.out)
    if out.suffix != ".npz":
        raise UserError(f"--out {out}: a Recording file must end in .npz")
    if out.is_dir():
        raise UserError(f"--out {out}: is a directory")
    if (args.base or args.tip) and not args.robot:
        raise UserError("--base/--tip select the chain of the --robot URDF: give --robot too")
    source = Path(args.source)
    if source.suffix.lower() in (".yaml", ".yml"):
        for flag, value in (("--topic", args.topic), ("--wrench-topic", args.wrench_topic)):
            if value is not None:
                raise UserError(f"{flag}: reads a bag; {source} is a mapping YAML (CSV/TXT logs)")
        rec = import_recording(load_mapping(source), data_dir=args.data_dir, robot_name=args.robot)
        if args.tau_kind is not None:
            rec.meta["tau_kind"] = args.tau_kind
        if args.robot:
            validate_recording(rec, load_robot_arg(args.robot, args), source=str(source))   # joint count and limits
    elif not source.exists():
        raise UserError(f"{source}: not found")
    elif is_bag(source):
        if not args.robot:
            raise UserError(f"{source}: a bag's joints are matched by name onto a robot description: give --robot "
                            "(a built-in name, a YAML or URDF file)")
        if args.data_dir is not None:
            raise UserError("--data-dir: resolves a mapping YAML's file names; a bag needs none")
        rec = import_bag(source, load_robot_arg(args.robot, args), topic=args.topic, wrench_topic=args.wrench_topic,
                         tau_kind=args.tau_kind)
        rec.meta["robot"] = args.robot
    else:
        raise UserError(f"{source}: neither a bag (a ROS 2 bag folder with metadata.yaml, a .mcap or .db3 file, a ROS 1 "
                        ".bag) nor a mapping YAML; a CSV/TXT log is read through a mapping YAML (format "
                        "proprio-import/v1, example: proprio/configs/import_tx40.yaml)")
    save_recording(rec, out)
    print(f"wrote {out}: {rec.n_samples} samples, {rec.duration:.3f} s at {rec.rate_hz:.6g} Hz, {rec.n_joints} "
          f"joints, tau_kind {rec.meta['tau_kind']}")
    for note in rec.meta.get("import", {}).get("notes", []):
        print(f"  note: {note}")
    with np.printoptions(precision=3, suppress=True, linewidth=120):
        print(f"  q range [rad]: min {rec.q.min(axis=0)}  max {rec.q.max(axis=0)}")
        print(f"  max |tau| [N·m]: {np.abs(rec.tau).max(axis=0)}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    from proprio.importer import TAU_KINDS

    p = subparsers.add_parser(
        "import", help="convert robot logs (ROS 1/ROS 2 bags, MCAP, or CSV/TXT with a mapping YAML) into a Recording",
        description="Two kinds of SOURCE. A ROS 2 bag folder (MCAP or sqlite3), a single .mcap/.db3 file or a ROS 1 "
                    ".bag: sensor_msgs/JointState (position, velocity, effort) matched by joint name onto --robot's "
                    "joint order (joints the robot lacks, e.g. a gripper, are ignored with a note), messages with "
                    "parts of the joints merged by header stamp, the header stamp as the time base (receive time "
                    "only when the messages carry no stamp, said so), geometry_msgs/WrenchStamped on --wrench-topic "
                    "as f_ext. A mapping YAML (format proprio-import/v1) for CSV/TXT logs: which columns are t, q, "
                    "q̇, τ or motor current, their units, gear ratios, torque constants and coupling (q = R⁻¹ "
                    "q_motor, τ = Rᵀ τ_motor), encoder offsets, the rate, and whether τ is a link-side sensor torque "
                    "or a drive torque (example: proprio/configs/import_tx40.yaml). Both are checked alike: NaN, "
                    "stamps that repeat (averaged, counted) or run backwards, radians, joint limits.")
    p.add_argument("source", type=Path, metavar="SOURCE",
                   help="a bag (ROS 2 folder, .mcap, .db3, ROS 1 .bag) or a mapping YAML (format proprio-import/v1)")
    p.add_argument("--out", required=True, help="output Recording (.npz)")
    p.add_argument("--robot", default=None,
                   help="robot description (built-in name, YAML or URDF file, or folder with robot.yaml): required "
                        "for a bag (joint names, order, limits); with a mapping it validates the joint count and "
                        "limits; written to meta.robot")
    p.add_argument("--topic", default=None, help="bag: the sensor_msgs/JointState topic (needed when the bag has "
                                                 "several; the error lists them)")
    p.add_argument("--wrench-topic", default=None,
                   help="bag: a geometry_msgs/WrenchStamped topic read as f_ext (the wrench on the robot at the "
                        "flange origin, world frame) [N, N·m]")
    p.add_argument("--tau-kind", choices=TAU_KINDS, default=None,
                   help="what τ is, written to meta.tau_kind: link_sensor (a joint-torque sensor behind the gear) "
                        "or drive (a drive torque from motor currents; the robot description then needs a drive "
                        "block with tau_kind: drive). Default: the mapping's tau_kind, for a bag the robot "
                        "description's drive.tau_kind, else link_sensor")
    p.add_argument("--data-dir", type=Path, default=None,
                   help="mapping only: folder the mapping's file names are relative to (default: the mapping's folder)")
    add_chain_args(p)
    p.set_defaults(func=_import)
