"""The time base of a log (step 1 of :mod:`proprio.conditioning`): the nominal step of jittered stamps, the uniform
grid and its gap flags, receive-time jitter moved onto the controller's regular clock, the gaps of a log and the
measured ranges between them, and the cubic-spline resampling onto the grid."""
from __future__ import annotations

import numpy as np
import scipy.interpolate

from proprio.recording import Recording

__all__ = ["clock_stamps", "uniform_time_base", "gap_steps", "measured_segments", "resample"]


def clock_stamps(t: np.ndarray, h: float) -> np.ndarray | None:
    """The stamps ``t`` [s] moved to a regular clock of step ≈ ``h``: ``c + h' · round((t − c) / h')``; None when two
    samples would share a tick (then the stamps cannot be receive-time jitter around that clock).

    The clock's step ``h'`` and phase ``c`` are refined by least squares on the ticks over a window growing 4× at a
    time from the first 256 samples, so that a step error of 1e-8 s cannot drift the ticks apart over a long log."""
    t = np.asarray(t, dtype=float)
    m = min(t.size, 256)
    while True:
        c = h * np.angle(np.mean(np.exp(2j * np.pi * t[:m] / h))) / (2 * np.pi)
        h, c = np.polyfit(np.round((t[:m] - c) / h), t[:m], 1)
        if m == t.size:
            break
        m = min(t.size, 4 * m)
    ticks = np.round((t - c) / h)
    return c + ticks * h if np.all(np.diff(ticks) >= 1) else None


def uniform_time_base(t: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray, float, list[str]]:
    """The uniform grid ``t_u`` [s, from 0] at the nominal step of ``t``, the ``valid [len(t_u)]`` flags (False inside
    steps longer than ``max_gap_s``), the step [s] and notes on what was found (jitter, gaps).

    The nominal step is the mean of the steps up to 1.5× their median: robust to lost samples, and right for a log
    whose steps alternate (the twin's "150 Hz" log of 6 and 7 ms steps has a 6.67 ms period, not a median one)."""
    t = np.asarray(t, dtype=float) - float(t[0])
    dt = np.diff(t)
    h = _nominal_step(dt)
    notes: list[str] = []
    jitter = float(np.max(np.abs(dt - h)))
    if jitter <= 1e-6 * h + 1e-12:
        return t, np.ones(t.size, dtype=bool), h, notes
    t_u = np.arange(int(np.floor(t[-1] / h + 1e-9)) + 1) * h
    valid = np.ones(t_u.size, dtype=bool)
    gaps = gap_steps(t, max_gap_s)
    if gaps.size:
        lo = np.searchsorted(t_u, t[gaps], side="right")
        hi = np.searchsorted(t_u, t[gaps + 1], side="left")
        mark = np.zeros(t_u.size + 1, dtype=int)
        np.add.at(mark, lo, 1)
        np.add.at(mark, hi, -1)
        valid = np.cumsum(mark[:-1]) == 0
        notes.append(f"{gaps.size} gap(s) > {1e3 * max_gap_s:.3g} ms, {int((~valid).sum())} samples flagged")
    notes.append(f"resampled from steps {1e3 * dt.min():.3g}–{1e3 * dt.max():.3g} ms")
    return t_u, valid, h, notes


def _nominal_step(dt: np.ndarray) -> float:
    return float(np.mean(dt[dt <= 1.5 * np.median(dt)]))


def gap_steps(t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Indices ``k`` of the steps ``t[k] → t[k+1]`` [s] that are gaps of the log (dropouts): longer than
    ``max(max_gap_s, 1.5 × the nominal step)`` — the rule of :func:`uniform_time_base`."""
    dt = np.diff(np.asarray(t, dtype=float))
    if dt.size == 0:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(dt > max(max_gap_s, 1.5 * _nominal_step(dt)))


def measured_segments(rec: Recording, max_gap_s: float) -> list[tuple[int, int]]:
    """``[(i0, i1), ...]``: the sample ranges ``rec.t[i0:i1]`` between the gaps of the log (:func:`gap_steps`), in
    order; one range covering everything when there is no gap. A stage that must not bridge a gap (a replay through
    the twin, which would otherwise move the arm through motion nobody measured) works on each range alone."""
    cuts = gap_steps(rec.t, max_gap_s) + 1
    bounds = np.r_[0, cuts, rec.n_samples]
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def resample(t: np.ndarray, x: np.ndarray, t_u: np.ndarray) -> np.ndarray:
    """Cubic-spline interpolation of ``x [N, ...]`` from ``t`` onto ``t_u`` (both from 0), vectorised over channels.
    Cubic, not linear: a linear segment across a long step puts kinks into q whose second difference would pose as
    acceleration (interpolation error ``≈ h⁴/384 · |q⁗|`` instead of ``h²/8 · |q̈|``)."""
    if t.shape == t_u.shape and np.array_equal(t, t_u):
        return np.asarray(x, dtype=float)
    return scipy.interpolate.make_interp_spline(t, np.asarray(x, dtype=float), k=3, axis=0)(t_u)
