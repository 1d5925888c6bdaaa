"""The ``proprio`` command line: one sub-command family per module in this package, each also a plain Python
function elsewhere in the library.

Every module ``proprio/cli/<name>.py`` that defines ``register(subparsers)`` is discovered automatically; its
``register`` adds one or more sub-parsers with ``set_defaults(func=...)``. A ``func(args) -> int`` returns the
exit code.

**Errors.** Every user error is one line ``proprio: error: …`` on stderr with exit code 2 and nothing written:
a bad command line (argparse), the project's bad-input family (:class:`proprio.errors.UserError` and the library's
``ValueError`` subclasses, whose messages name the field or file), an OS error on a user's path, a YAML syntax
error. Output paths are checked (:func:`check_output`) before any long work. Anything else is a bug and keeps its
traceback.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import math
import pkgutil
import sys
import warnings


import tempfile
from pathlib import Path
from typing import Callable, NoReturn

import yaml

from proprio.errors import UserError

__all__ = ["main", "build_parser", "UserError", "check_output", "check_recording_robot", "add_plugin_args", "add_chain_args", "load_robot_arg", "finite", "nonnegative", "positive",
           "positive_int", "nonnegative_int"]


class _CommandLineError(Exception):
    """A bad command line (raised by the parser, reported by :func:`main` like every user error)."""


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are the command line's one line (not argparse's usage + error)."""

    def error(self, message: str) -> NoReturn:
        raise _CommandLineError(f"{self.prog}: {message} (see '{self.prog} --help')")


def _number(kind: type, ok: Callable[[float], bool], what: str) -> Callable[[str], float]:
    """An argparse ``type``: ``kind(text)``, finite and ``ok``, else argparse's error naming the flag and ``what``."""
    def convert(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not (math.isfinite(value) and ok(value)):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value
    convert.__name__ = what
    return convert


finite = _number(float, lambda v: True, "a finite number")
nonnegative = _number(float, lambda v: v >= 0, "a finite number >= 0")
positive = _number(float, lambda v: v > 0, "a finite number > 0")
positive_int = _number(int, lambda v: v >= 1, "an integer >= 1")
nonnegative_int = _number(int, lambda v: v >= 0, "an integer >= 0")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
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


def add_plugin_args(p: argparse.ArgumentParser) -> None:
    """``--allow-plugin MODULE:CLASS`` (repeatable): the user's consent to import a plugin effect that a config
    names (:mod:`proprio.effects.plugins`); a config alone never imports code."""
    p.add_argument("--allow-plugin", action="append", default=[], metavar="MODULE:CLASS",
                   help="allow a config (twin YAML, twin_patch.yaml, --effects-config) to use this plugin effect, "
                        "importing its module; repeatable (plugins installed as 'proprio.effects' entry points need "
                        "no flag)")


def add_chain_args(p: argparse.ArgumentParser) -> None:
    """``--base LINK``/``--tip LINK``: select the serial chain of a URDF robot where it is ambiguous (read with
    :func:`load_robot_arg`)."""
    p.add_argument("--base", metavar="LINK", default=None,
                   help="with a URDF robot: the link the serial chain starts at (only needed where it is ambiguous)")
    p.add_argument("--tip", metavar="LINK", default=None,
                   help="with a URDF robot: the link the serial chain ends at, e.g. tool0 when a gripper's fingers "
                        "branch off it (only needed where it is ambiguous)")


def load_robot_arg(value: str, args: argparse.Namespace):
    """The robot description of a ``--robot``/``--model`` value, with the chain of ``--base``/``--tip``."""
    from proprio.description import load_robot

    return load_robot(value, args.base, args.tip)


def check_recording_robot(rec, robot, path: str | Path, flag: str, twin: bool = False):
    """The one check that a Recording was made on ``robot`` (the model of a command; ``flag`` names the option that
    gives it): joint count, limits and — when ``meta.robot`` names another robot — the same kinematics
    (:func:`proprio.diagrams.estimation.check_recording_matches`). A mismatch is a :class:`UserError` whose advice is
    a ``flag`` value that loads: ``meta.robot`` itself when it is a description, or the folder of the recording when
    it holds that robot's ``robot.yaml`` (the LWR 4+ files); with ``twin`` (``flag`` takes a twin config) a twin config
    of that robot."""
    from proprio.diagrams.estimation import check_recording_matches
    from proprio.recording import RecordingError

    try:
        return check_recording_matches(rec, robot)
    except RecordingError as exc:
        name = rec.meta.get("robot")
        text = f"{path}: {str(exc).removeprefix('recording: ')}"
        if not name or name == robot.name:
            raise UserError(text) from None
        found = None if twin else _description_of(name, Path(path))
        advice = (f"pass {flag} {found}" if found else f"pass {flag} with a twin config of robot '{name}'" if twin else
                  f"pass {flag} with the description of '{name}' (a robot YAML/URDF or a folder with its robot.yaml)")
        raise UserError(f"{text}; {advice}") from None


def _description_of(name: str, path: Path) -> str | None:
    """A ``--model``/``--robot`` value that loads robot ``name``: the name itself, or the recording's folder when its
    ``robot.yaml`` is that robot; None when neither is."""
    from proprio.description import load_robot

    for spec in (name, str(path.parent)):
        try:
            if load_robot(spec).name == name:
                return spec
        except (ValueError, OSError):
            continue
    return None


def check_output(path: str | Path | None, flag: str, kind: str = "file") -> None:
    """Refuse, before any work, an output ``path`` (``kind`` ``"file"`` or ``"dir"``) that cannot be written: a
    directory where a file goes (or the reverse), a parent that is a file, a folder without write permission."""
    if path is None:
        return
    path = Path(path)
    if kind == "file" and path.is_dir():
        raise UserError(f"{flag} {path}: is a directory; give a file name")
    if kind == "dir" and path.exists() and not path.is_dir():
        raise UserError(f"{flag} {path}: exists and is not a directory")
    folder = path if kind == "dir" else path.parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise UserError(f"{flag} {path}: {folder} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise UserError(f"{flag} {path}: cannot write in {folder} ({exc.strerror or exc})") from None


# where a loader starts its advice to load pickles anyway (loading pickles runs code): never passed on
_PICKLE_ADVICE = ("Weights only load failed", "This file contains pickled", "Object arrays cannot be loaded",
                  "allow_pickle", "weights_only", "pickle.load", "unsafely")


def _one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line; a loader's text about pickles is replaced by proprio's own word."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    cut = min((i for i in (text.find(k) for k in _PICKLE_ADVICE) if i >= 0), default=-1)
    if cut >= 0:
        head = text[:cut].rstrip(" (:;,-")
        text = f"{head}: the file holds pickled Python objects, which proprio never loads" + \
            ")" * max(head.count("(") - head.count(")"), 0)
    return text.strip() or type(exc).__name__


class _OneInertiaWarning(logging.Filter):
    """Drake's warning for every link inertia that fails ``CouldBePhysicallyValid`` (a model identified without
    ``--method sdp``: ≈ 8 lines per link, each time a plant is built) becomes one line, once per run."""

    def __init__(self) -> None:
        super().__init__()
        self.said = False

    def filter(self, record: logging.LogRecord) -> bool:
        if "CouldBePhysicallyValid" not in record.getMessage():
            return True
        if self.said:
            return False
        self.said = True
        record.msg, record.args = (INERTIA_WARNING, ())
        return True


INERTIA_WARNING = ("the model's link inertias are not physically valid (Drake: CouldBePhysicallyValid fails; further "
                   "such warnings are not shown), as an OLS/WLS identification may give; `proprio identify "
                   "--method sdp` gives a physically consistent model")


def main(argv: list[str] | None = None) -> int:
    warnings.formatwarning = _warning_line   # a library warning (e.g. a repaired inertia) is one line, no source
    drake_log = logging.getLogger("drake")
    for old in [f for f in drake_log.filters if isinstance(f, _OneInertiaWarning)]:
        drake_log.removeFilter(old)
    drake_log.addFilter(_OneInertiaWarning())
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _CommandLineError as exc:
        print(f"proprio: error: {exc}", file=sys.stderr)
        return 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        if getattr(args, "allow_plugin", None):
            from proprio.effects.plugins import allow_plugins
            allow_plugins(args.allow_plugin)
        return int(args.func(args) or 0)
    except BrokenPipeError:  # e.g. `proprio inspect FILE | head`
        sys.stderr.close()
        return 0
    except (ValueError, OSError, yaml.YAMLError) as exc:
        # the project's bad-input family (UserError and the library's ValueErrors), OS errors on the user's paths,
        # YAML syntax errors: one line, even when the message carries a parser's multi-line report
        print(f"proprio: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("proprio: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
