"""The ``proprio`` command line: one sub-command family per module in this package, each also a plain Python
function elsewhere in the library.

Every module ``proprio/cli/<name>.py`` that defines ``register(subparsers)`` is discovered automatically; its
``register`` adds one or more sub-parsers with ``set_defaults(func=...)``. A ``func(args) -> int`` returns the
exit code. User errors (bad input files, bad configs) raise :class:`UserError` or ``ValueError`` subclasses and are
printed as one line ``proprio: error: ...`` with exit code 2.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import warnings

__all__ = ["main", "build_parser", "UserError"]


class UserError(Exception):
    """An error caused by the user's input; printed without a traceback, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="proprio",
        description="Torque-sensing arm twin, identification, wrench estimation and sim-to-real gap diagnosis.")
    parser.add_argument("--version", action="version", version=f"proprio {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "register"):
            module.register(sub)
    return parser


def _version() -> str:
    from proprio import __version__
    return __version__


def _warning_line(message, category, filename, lineno, line=None) -> str:
    return f"proprio: warning: {message}\n"


def main(argv: list[str] | None = None) -> int:
    warnings.formatwarning = _warning_line   # a library warning (e.g. a repaired inertia) is one line, no source
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (UserError, ValueError, FileNotFoundError) as exc:
        # one line, even when the message carries a parser's multi-line report (e.g. a YAML syntax error)
        message = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        print(f"proprio: error: {message}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `proprio inspect FILE | head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("proprio: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
