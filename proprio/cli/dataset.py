"""``proprio dataset``: simulate the twin over many RFMA seeds × payloads into a dataset directory (+ manifest)."""
from __future__ import annotations

import argparse
from pathlib import Path

from proprio.cli._backend import add_backend_args, check_backend_args, clear_state
from proprio.cli import UserError, add_plugin_args, check_output, nonnegative, nonnegative_int, positive, positive_int
from proprio.cli.flags import add_list, add_quiet, add_twin

__all__ = ["register"]


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "dataset", help="simulate the twin over many RFMA seeds/payloads into a dataset directory with a manifest",
        description="One task per (RFMA seed, payload): generate the RFMA trajectory of the seed, simulate the twin "
                    "along it and write OUT/rfma_s<SEED>_p<PAYLOAD>kg.npz; OUT/manifest.json lists what was "
                    "simulated with which twin config (and its SHA-256), which seeds and payloads, and each "
                    "recording's data and file digests. Tasks run here or on Ray (--backend ray [--address]); the "
                    "recordings are identical either way. A rerun simulates only what is missing.")
    add_twin(p, "iiwa14_twin", "")
    add_list(p, "--seeds", required=True, metavar="SEED",
                   help="RFMA trajectory seeds: integers or inclusive ranges A-B (e.g. 11 12 13 or 20-29)")
    add_list(p, "--payload-kg", type=nonnegative, default=[0.0], metavar="M",
                   help="payload masses at the flange [kg], each simulated on every seed (default 0)")
    p.add_argument("--scaffolds", type=positive_int, default=150,
                   help="RFMA scaffolds per trajectory (default 150, ≈1 h)")
    p.add_argument("--seconds", type=positive, default=None, help="simulate only the first SECONDS of each trajectory")
    p.add_argument("--log-rate", type=positive, default=None, help="log rate [Hz] (default: the twin config's)")
    p.add_argument("--twin-seed", type=nonnegative_int, default=None,
                   help="noise seed of the twin for every recording (default: each trajectory's seed)")
    p.add_argument("--out", required=True, type=Path, help="dataset directory")
    add_quiet(p)
    add_backend_args(p, "1 for local, os.cpu_count() for a local Ray instance")
    add_plugin_args(p)
    p.set_defaults(func=_dataset)


def _dataset(args: argparse.Namespace) -> int:
    from proprio.experiments.dataset import DatasetSpec, build_dataset, seeds_from

    check_output(args.out, "--out", "dir")
    check_backend_args(args)
    seeds = seeds_from(args.seeds)
    if any(s < 0 for s in seeds):
        raise UserError(f"--seeds: seeds are integers >= 0, got {min(seeds)}")
    spec = DatasetSpec(twin=args.twin, seeds=seeds, payloads_kg=tuple(args.payload_kg),
                       scaffolds=args.scaffolds, seconds=args.seconds, log_rate_hz=args.log_rate,
                       twin_seed=args.twin_seed)
    clear_state(args.out / ".tasks", args.restart)
    manifest, run = build_dataset(spec, args.out, backend=args.backend, address=args.address, workers=args.workers,
                                  progress=not args.quiet)
    total = sum(r["duration_s"] for r in manifest["recordings"])
    print(run.summary())
    print(f"{len(manifest['recordings'])} recording(s), {total / 60:.1f} min of motion -> {args.out / 'manifest.json'}")
    return 0 if not run.failures else 1
