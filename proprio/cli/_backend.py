"""The options every parallel command shares (``dataset``, ``gap-benchmark``, ``train-grid``): ``--backend``,
``--address``, ``--workers``, ``--restart``; see :mod:`proprio.tasks`."""
from __future__ import annotations

import argparse
import shutil
import socket
from pathlib import Path

from proprio.cli import UserError, positive_int

__all__ = ["add_backend_args", "check_backend_args", "clear_state", "ADDRESS_TIMEOUT_S"]

ADDRESS_TIMEOUT_S = 5.0      # a Ray cluster that does not accept a connection within this is reported unreachable


def add_backend_args(p: argparse.ArgumentParser, workers_default: str) -> None:
    p.add_argument("--backend", choices=("local", "ray"), default="local",
                   help="where the tasks run: 'local' (this machine: in this process or --workers processes) or "
                        "'ray' (Ray tasks: a local Ray instance with --workers CPUs, or the cluster at --address); "
                        "results are identical either way (default local)")
    p.add_argument("--address", metavar="ADDR", default=None,
                   help="Ray cluster to run on with --backend ray: 'auto' (the cluster this machine joined with "
                        "'ray start'), HOST:6379, or ray://HOST:10001 (Ray Client); default: start a local Ray "
                        "instance")
    p.add_argument("--workers", type=positive_int, default=None,
                   help=f"parallel workers: processes (local) or CPUs of the local Ray instance (default "
                        f"{workers_default})")
    p.add_argument("--restart", action="store_true",
                   help="forget the finished tasks in --out and run everything again (default: a rerun only runs "
                        "what is missing)")


def check_backend_args(args: argparse.Namespace) -> None:
    if args.address and args.backend != "ray":
        raise UserError("--address needs --backend ray")
    if args.backend == "ray":
        if args.address and args.address != "auto":
            _check_reachable(args.address)
        from proprio.tasks import import_ray
        import_ray()


def _check_reachable(address: str) -> None:
    """A one-line error, within :data:`ADDRESS_TIMEOUT_S`, for a ``--address`` HOST:PORT (or ray://HOST:PORT) where
    nothing accepts a connection (Ray itself would wait much longer, silently)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise UserError(f"--address {address}: expected 'auto', HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=ADDRESS_TIMEOUT_S).close()
    except OSError as exc:
        raise UserError(f"--address {address}: no Ray cluster answers there within {ADDRESS_TIMEOUT_S:g} s "
                        f"({exc.strerror or exc})") from None


def clear_state(state_dir: Path, restart: bool) -> Path:
    """``state_dir`` (the per-task result files), emptied first with ``--restart``."""
    if restart and state_dir.exists():
        shutil.rmtree(state_dir)
    return state_dir
