"""The flags several commands share, each declared once here: one name, one meaning, one unit in every command.

| flag | unit | commands |
|---|---|---|
| ``--trim`` | s, dropped at both ends of every recording | identify, diagnose, simulate --replay |
| ``--cutoff-hz`` | Hz or ``auto``: the conditioning's zero-phase low-pass | identify, diagnose, estimate, payload-experiment, view |
| ``--split-at`` | s: train on the first S s of every training recording, hold out the rest | identify, diagnose |
| ``--holdout-fraction`` | share of every training recording's length held out at its end | identify, diagnose |
| ``--quiet`` | no progress bar (bars are drawn only on a terminal anyway) | simulate, twin hysteresis-test, dataset |
| ``--twin`` | a twin config (shipped name or YAML) | simulate, dataset, twin hysteresis-test, payload-experiment, diagnose |

A flag that takes a list (``--train A B``) accumulates when given twice (``--train A --train B`` is ``A B``), in
every command (:func:`add_list`): a second occurrence never silently replaces the first.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

from proprio.errors import UserError

__all__ = ["add_list", "add_trim", "add_cutoff_hz", "cutoff_hz", "conditioning_of", "add_split", "split_tails",
           "add_quiet", "add_twin"]


class _Accumulate(argparse.Action):
    """``nargs`` list flag that extends its list on every occurrence; the default is replaced (not extended) by the
    first occurrence."""

    def __call__(self, parser, namespace, values, option_string=None):
        items = getattr(namespace, self.dest, None)
        items = [] if items is None or items is self.default else list(items)
        setattr(namespace, self.dest, items + list(values))


def add_list(p: argparse.ArgumentParser, *names: str, nargs: str = "+", **kw) -> argparse.Action:
    """A list flag (``nargs`` ``+`` or ``*``) that accumulates over repeated occurrences (module docstring)."""
    return p.add_argument(*names, nargs=nargs, action=_Accumulate, **kw)


def add_trim(p: argparse.ArgumentParser, default: float | None, default_text: str, what: str = "") -> None:
    """``--trim SECONDS``: seconds dropped at both ends of every recording (the conditioning filters' start-up)."""
    from proprio.cli import nonnegative

    p.add_argument("--trim", type=nonnegative, default=default, metavar="SECONDS",
                   help=f"seconds dropped at both ends of every recording{what} (filter start-up; default "
                        f"{default_text})")


def cutoff_hz(text: str) -> float | str:
    """The argparse ``type`` of ``--cutoff-hz``: a finite number > 0 [Hz] or ``auto``."""
    if text == "auto":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number [Hz] > 0 or 'auto', got {text!r}") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a number [Hz] > 0 or 'auto', got {text!r}")
    return value


cutoff_hz.__name__ = "--cutoff-hz"


def add_cutoff_hz(p: argparse.ArgumentParser, what: str = "") -> None:
    """``--cutoff-hz HZ|auto``: the cutoff of the one signal-conditioning path's zero-phase low-pass
    (:mod:`proprio.conditioning`); ``auto`` (the default) sets it per joint from the data's noise floor."""
    p.add_argument("--cutoff-hz", type=cutoff_hz, default="auto", metavar="HZ|auto",
                   help=f"zero-phase low-pass cutoff of the signal conditioning{what} [Hz], or 'auto' (per joint from "
                        "the data's noise floor; default)")


def conditioning_of(args: argparse.Namespace, base=None):
    """The :class:`~proprio.conditioning.ConditioningConfig` ``base`` (default: the library's) with ``--cutoff-hz``."""
    import dataclasses

    from proprio.conditioning import ConditioningConfig

    return dataclasses.replace(base or ConditioningConfig(), cutoff_hz=args.cutoff_hz)


def add_split(p: argparse.ArgumentParser, default_fraction: float | None, default_text: str) -> None:
    """``--split-at SECONDS`` / ``--holdout-fraction F`` (one of them): hold out the end of every training recording
    (read with :func:`split_tails`)."""
    from proprio.cli import positive

    g = p.add_mutually_exclusive_group()
    g.add_argument("--split-at", type=positive, default=None, metavar="SECONDS",
                   help="train on the first SECONDS of every --train recording and hold out the rest")
    g.add_argument("--holdout-fraction", type=_fraction, default=default_fraction, metavar="F",
                   help=f"hold out the last F (0 < F < 1) of every --train recording's length and train on the rest "
                        f"(default {default_text})")


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction 0 < F < 1, got {text!r}") from None
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"expected a fraction 0 < F < 1, got {text!r}")
    return value


_fraction.__name__ = "--holdout-fraction"


def split_tails(args: argparse.Namespace, recs: Sequence, paths: Sequence[str | Path]) -> tuple[list, list, list[str]]:
    """The training recordings cut by ``--split-at`` / ``--holdout-fraction``: ``(heads, tails, tail_names)``; the
    heads train, the tails are held out. Neither flag set: ``(recs, [], [])``. A cut outside a recording's time span
    raises :class:`UserError` naming the file."""
    import numpy as np

    if args.split_at is None and args.holdout_fraction is None:
        return list(recs), [], []
    heads, tails, names = [], [], []
    for path, rec in zip(paths, recs):
        if args.split_at is not None:
            at, said, flag = args.split_at, f"{args.split_at:g} s", f"--split-at {args.split_at:g} s"
        else:
            at = (1.0 - args.holdout_fraction) * (rec.t[-1] - rec.t[0])
            said, flag = f"{at:.3g} s", f"--holdout-fraction {args.holdout_fraction:g} (a cut at {at:.3g} s)"
        cut = int(np.searchsorted(rec.t, rec.t[0] + at))
        if not 0 < cut < rec.n_samples:
            raise UserError(f"{flag} leaves no sample on one side in {path} ({rec.n_samples} samples over "
                            f"{rec.t[-1] - rec.t[0]:.3g} s)")
        heads.append(rec.slice(0, cut))
        tail = rec.slice(cut, rec.n_samples)
        try:                    # the tail on the session clock where it was measured (meta.session_time_s: at t[0])
            tail.meta["session_time_s"] = float(rec.meta.get("session_time_s", 0.0)) + float(rec.t[cut] - rec.t[0])
        except (TypeError, ValueError):
            pass                # a bad value is named by the stage that reads it
        tails.append(tail)
        names.append(f"{path} after {said}")
    return heads, tails, names


def add_twin(p: argparse.ArgumentParser, default: str | None, what: str, *aliases: str) -> None:
    """``--twin TWIN``: a twin config, a shipped name or a YAML path (:func:`proprio.diagrams.twin.load_twin_config`);
    ``what`` says what the command does with it. (``gap-benchmark --twin`` is a switch of its own: record the cases
    through the twin.)"""
    said = f" (default {default})" if default else ""
    p.add_argument("--twin", *aliases, default=default, metavar="TWIN",
                   help=f"twin config: a shipped name (iiwa14_twin, iiwa14_nominal_twin, kuka_lwr4_twin, "
                        f"staubli_tx40_twin) or a YAML path{what}{said}")


def add_quiet(p: argparse.ArgumentParser) -> None:
    """``--quiet``: no progress bar (on a terminal; elsewhere there is none: :mod:`proprio.progress`)."""
    p.add_argument("--quiet", action="store_true", help="no progress bar (one is drawn only on a terminal)")
