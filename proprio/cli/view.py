"""``proprio view SOURCE``: play a Recording, a twin run or an estimation result in Drake's Meshcat — the arm moving,
the estimated and the true flange force as arrows, each link tinted by its joint's torque residual, with a time
slider — live on localhost, or as one self-contained HTML file (``--html``).

A thin wrapper: :func:`proprio.diagrams.playback.load_playback`, :func:`~proprio.diagrams.playback.record_playback`
and :func:`~proprio.diagrams.playback.write_playback_html` do the work.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from proprio.cli import UserError, check_output, finite, nonnegative
from proprio.cli.flags import add_cutoff_hz, conditioning_of

__all__ = ["register", "run_view"]


def _settings(args: argparse.Namespace):
    from proprio.diagrams.playback import PlaybackSettings
    try:
        return PlaybackSettings(fps=args.fps, max_frames=args.max_frames, force_scale=args.force_scale,
                                residual_scale=args.residual_scale)
    except ValueError as exc:
        raise UserError(f"--{str(exc).replace('_', '-')}") from None


def _describe(info) -> str:
    fr = info.frames
    text = (f"{fr.count} frames at {info.fps:g} fps ({fr.period * 1e3:.1f} ms of data each, ×{fr.speedup:.2f} real "
            f"time); arrows {100 * info.force_scale:g} cm/N: {', '.join(info.arrow_paths) or 'none'}")
    if info.residual_scale is not None:
        text += f"; link tint saturates at ±{info.residual_scale:.3g} N·m"
    if info.hidden.any():
        text += (f"; {int(info.hidden.sum())} frames fall inside gaps of the log and show nothing (no motion is "
                 "invented there)")
    return text


def run_view(args: argparse.Namespace) -> int:
    from proprio.diagrams.playback import load_playback, record_playback, start_meshcat, write_playback_html

    settings = _settings(args)
    check_output(args.html, "--html", "file")
    pb = load_playback(args.source, model=args.model, observer=args.observer, start_s=args.start, end_s=args.end,
                       conditioning=conditioning_of(args))
    if args.html is not None:
        path, info = write_playback_html(pb, args.html, settings)
        print(_describe(info))
        print(f"wrote {path} (open it in a browser; no server needed)")
        return 0
    meshcat = start_meshcat(args.port)
    info = record_playback(pb, meshcat, settings)
    print(_describe(info))
    print(f"Meshcat: {meshcat.web_url()} (localhost only) — time slider: Open Controls → Animations → time")
    try:
        if args.serve_seconds is not None:
            time.sleep(args.serve_seconds)
        else:
            print("serving until Ctrl-C", flush=True)
            while True:
                time.sleep(1.0)
    except KeyboardInterrupt:
        print("stopped")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "view", help="play a Recording, a twin run or an estimation result in Meshcat (live, or --html FILE)",
        description="Play a run in Drake's Meshcat: the arm moving, the estimated (observer) and the true flange "
                    "force as arrows, and each link tinted by its joint's torque residual e = τ_J − τ_model + "
                    "Jᵀf_true (grey 0, red +, blue −), with a time slider (Open Controls → Animations). SOURCE is a "
                    "Recording .npz (a twin run from `proprio simulate`, a measured log, an LWR 4+ file; the "
                    "estimation diagram of `proprio estimate` runs over it with --model) or an estimates.npz from `proprio estimate` (or its "
                    "output directory). Frames: 30 per second of the run up to --max-frames; longer runs play "
                    "faster, each frame showing the mean of its group of samples. Without --html a Meshcat server "
                    "runs on localhost until Ctrl-C.")
    p.add_argument("source", type=Path, help="Recording .npz, or estimates.npz / the directory holding it")
    p.add_argument("--model", help="the dynamics model of the observers (a Recording) or the robot to draw (an "
                   "estimates file): a shipped robot name, robot YAML/URDF/directory, identified .npz or hybrid .pt "
                   "(default: the robot the file names)")
    p.add_argument("--observer", choices=("jacobian", "momentum"), default="jacobian",
                   help="whose force estimate to draw (default jacobian)")
    p.add_argument("--html", type=Path, metavar="FILE", help="write a self-contained HTML animation and exit")
    p.add_argument("--start", type=finite, metavar="S", help="start of the window to play [s from the start]")
    p.add_argument("--end", type=finite, metavar="S", help="end of the window to play [s from the start]")
    p.add_argument("--fps", type=float, default=30.0, help="animation frames per second (default 30)")
    p.add_argument("--max-frames", type=int, default=1800, help="at most this many frames (default 1800 = 1 min "
                   "at 30 fps); a longer run plays faster than real time")
    p.add_argument("--force-scale", type=float, default=0.02, help="arrow length per force [m/N] (default 0.02)")
    p.add_argument("--residual-scale", type=float, help="residual [N·m] at full tint (default: the 95th "
                   "percentile of |e|, at least 0.1)")
    add_cutoff_hz(p, " of a Recording")
    p.add_argument("--port", type=int, help="Meshcat port on localhost (default: the first free one from 7000)")
    p.add_argument("--serve-seconds", type=nonnegative, metavar="S",
                   help="without --html: stop serving after S seconds "
                   "(default: until Ctrl-C)")
    p.set_defaults(func=run_view)
