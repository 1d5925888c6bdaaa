"""The robot's logger, as laws: what a real arm's log contains, as opposed to what the simulation knows.

A real arm's log (the iiwa over FRI, the LWR 4+ through its research interface, a ROS 2 bag) holds time stamps with
jitter and lost samples, the encoder ``q`` and the torque sensors' ``τ_J`` — sometimes the controller's own filtered
``q̇``, never ``q̈``. The twin's exact ``q̇``, ``q̈`` and its true sampling instants go to ``truth__*`` channels only.

The model (the ``logger:`` block of a twin config, :class:`LoggerConfig`), applied to the twin's samples piece by
piece (vectorised over each piece, the state between pieces in :class:`LoggerCarry`; the twin's Diagram applies it
once per block of samples, :mod:`proprio.diagrams.twin_chain`), seeded by the twin's seed:

* **rate** — the twin steps at ``1/time_step``; the robot logs at ``rate_hz``, the nearest step to each nominal
  instant (:func:`logged_steps`; 150 Hz → 6/7 ms steps like the iiwa);
* **samples lost** — a burst of ``1 … dropout_max_samples`` consecutive samples is lost after any sample with
  probability ``dropout_prob`` (a late packet the host never logged), so a step of ``k + 1`` nominal periods appears
  (overlapping bursts merge, and a run of lost samples never exceeds ``dropout_max_samples``); the first and the
  last sample of a run are always kept;
* **time stamps** — each kept sample is stamped ``t_true + e`` with ``e ~ N(0, stamp_jitter_ms)`` clipped to ±3σ
  (host receive time instead of the controller's sampling instant). ``3σ`` must stay below half the nominal step,
  so the stamps stay strictly increasing;
* **channels** — ``q`` and ``tau`` always; ``qd`` only when listed, as the controller's own estimate: the backward
  difference of the encoder ``q`` through a causal first-order low-pass at ``qd_filter_hz`` (computed at ``rate_hz``
  before samples are lost, as a controller does), i.e. with the phase lag a real robot's q̇ has.

Each random draw has its own stream (:mod:`proprio.random_streams`: ``logger_dropout``, ``logger_burst``,
``logger_jitter``), so the sensors' noise of a given sample does not change when the logger's settings do, and a
run logged in pieces equals the run logged at once (tests).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import scipy.signal

from proprio.random_streams import STATE_SIZE, generator_from_state, generator_state, stream
from proprio.typed_yaml import load_typed

__all__ = ["LoggerConfig", "LoggerCarry", "LoggedPiece", "RobotLogger", "logged_steps", "LOGGER_STREAMS"]

LOGGER_STREAMS = ("logger_dropout", "logger_burst", "logger_jitter")

_CHANNELS = ("q", "tau", "qd")


@dataclass(frozen=True)
class LoggerConfig:
    """The ``logger:`` block of a twin config (module docstring): ``rate_hz`` [Hz], ``channels`` (``q``, ``tau``
    and optionally ``qd``), ``qd_filter_hz`` [Hz] (the robot's own q̇ filter, required with ``qd``),
    ``stamp_jitter_ms`` [ms] (σ of the stamp error), ``dropout_prob`` (per sample) and ``dropout_max_samples``."""
    rate_hz: float = 1000.0
    channels: tuple[str, ...] = ("q", "tau")
    qd_filter_hz: float | None = None
    stamp_jitter_ms: float = 0.0
    dropout_prob: float = 0.0
    dropout_max_samples: int = 1

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None, time_step: float, where: str = "logger") -> "LoggerConfig":
        """Parse (strictly, :mod:`proprio.typed_yaml`) and check a ``logger:`` mapping for a twin stepping at
        ``time_step`` [s]; ``rate_hz`` defaults to ``1/time_step``. Errors name the field (and the nearest key)."""
        cfg = load_typed(cls, d, where, ValueError)
        if "rate_hz" not in (d or {}):
            cfg = replace(cfg, rate_hz=1.0 / time_step)
        cfg.check(time_step, where)
        return cfg

    def check(self, time_step: float, where: str = "logger") -> None:
        if not 0 < self.rate_hz <= 1.0 / time_step + 1e-9:
            raise ValueError(f"{where}.rate_hz must be in (0, 1/time_step = {1 / time_step:g}] Hz, got {self.rate_hz}")
        bad = [c for c in self.channels if c not in _CHANNELS]
        if bad or "q" not in self.channels or "tau" not in self.channels:
            raise ValueError(f"{where}.channels must contain q and tau and may add qd; got {list(self.channels)}")
        if "qd" in self.channels:
            if self.qd_filter_hz is None or not 0 < float(self.qd_filter_hz) < 0.5 * self.rate_hz:
                raise ValueError(f"{where}.qd_filter_hz: a robot that reports q̇ needs its filter's cutoff in "
                                 f"(0, {0.5 * self.rate_hz:g}) Hz, got {self.qd_filter_hz}")
        elif self.qd_filter_hz is not None:
            raise ValueError(f"{where}.qd_filter_hz is set but 'qd' is not in channels {list(self.channels)}")
        if not 0 <= 3e-3 * self.stamp_jitter_ms < 0.5 / self.rate_hz:
            raise ValueError(f"{where}.stamp_jitter_ms must be >= 0 and 3σ below half the step "
                             f"({0.5e3 / self.rate_hz:g} ms), got {self.stamp_jitter_ms}")
        if not 0 <= self.dropout_prob < 0.5 or self.dropout_max_samples < 1:
            raise ValueError(f"{where}: dropout_prob must be in [0, 0.5) and dropout_max_samples >= 1, got "
                             f"{self.dropout_prob}, {self.dropout_max_samples}")

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "channels": list(self.channels)}




def logged_steps(lo: int, hi: int, n_steps: int, time_step: float, rate_hz: float) -> np.ndarray:
    """Indices in ``[lo, hi)`` of the twin's steps (``n_steps`` of ``time_step`` [s] in the run) that a robot logging at
    ``rate_hz`` [Hz] keeps: the nearest step to each nominal instant ``k / rate_hz`` before the run's end (the last
    step at most). Every step at ``rate_hz = 1/time_step``."""
    hi = min(hi, n_steps)
    if abs(rate_hz * time_step - 1.0) < 1e-9:
        return np.arange(lo, hi)
    step = 1.0 / rate_hz
    count = math.ceil(n_steps * time_step / step)             # len(np.arange(0, n_steps·time_step, step))
    ratio = rate_hz * time_step
    k = np.arange(max(0, math.floor((lo - 1) * ratio)), min(count, math.ceil((hi + 1) * ratio) + 1))
    idx = np.unique(np.minimum(np.round(k * step / time_step).astype(int), n_steps - 1))
    return idx[(idx >= lo) & (idx < hi)]


@dataclass(frozen=True)
class LoggerCarry:
    """The logger's state between pieces of a run, as numbers (``[size]``, :meth:`vector`): samples seen, the bursts
    still open at the piece's end (``active``, and ``pending[m + 1]`` burst starts/ends ahead, m =
    ``dropout_max_samples``), the length of the run of lost samples at the end (``run``), the first stamp (the log's
    zero, NaN before any), the robot's q̇ filter (last encoder ``q [n]``, its state ``zi [n]``) and the three
    streams' states (``LOGGER_STREAMS``)."""
    seen: float
    active: float
    pending: np.ndarray
    run: float
    stamp0: float
    q_last: np.ndarray
    zi: np.ndarray
    streams: np.ndarray

    def vector(self) -> np.ndarray:
        return np.concatenate([[self.seen, self.active], self.pending, [self.run, self.stamp0], self.q_last, self.zi,
                               self.streams])

    @classmethod
    def size(cls, n: int, config: LoggerConfig) -> int:
        return 4 + config.dropout_max_samples + 1 + 2 * n + len(LOGGER_STREAMS) * STATE_SIZE

    @classmethod
    def from_vector(cls, v: np.ndarray, n: int, config: LoggerConfig) -> "LoggerCarry":
        m = config.dropout_max_samples + 1
        q0 = 4 + m
        return cls(float(v[0]), float(v[1]), v[2:2 + m].copy(), float(v[2 + m]), float(v[3 + m]),
                   v[q0:q0 + n].copy(), v[q0 + n:q0 + 2 * n].copy(), v[q0 + 2 * n:].copy())


@dataclass
class LoggedPiece:
    """What :meth:`RobotLogger.log` keeps of a piece: ``keep [M]`` indices into the piece's samples, their ``stamps
    [M]`` [s] on the log's clock (the run's first stamp is 0) and the robot's own ``qd [M, n]`` [rad/s] (None unless
    the logger reports it)."""
    keep: np.ndarray
    stamps: np.ndarray
    qd: np.ndarray | None


class RobotLogger:
    """Applies a :class:`LoggerConfig` to samples taken at its ``rate_hz``, piece by piece (:meth:`log`)."""

    def __init__(self, config: LoggerConfig, n: int, seed: int):
        self.config, self.n, self.seed = config, n, int(seed)
        self._b, self._a = (scipy.signal.butter(1, float(config.qd_filter_hz), fs=config.rate_hz)
                            if "qd" in config.channels else (None, None))

    def start(self) -> LoggerCarry:
        """The state before the run's first sample."""
        m = self.config.dropout_max_samples + 1
        return LoggerCarry(0.0, 0.0, np.zeros(m), 0.0, math.nan, np.full(self.n, math.nan), np.zeros(self.n),
                           np.concatenate([generator_state(stream(self.seed, k)) for k in LOGGER_STREAMS]))

    def robot_velocity(self, q_encoder: np.ndarray, carry: LoggerCarry) -> tuple[np.ndarray, np.ndarray]:
        """The controller's own q̇ [rad/s] ``[N, n]`` and the filter's state after it: backward difference of the
        encoder ``q [N, n]`` at ``rate_hz`` (the run's first difference 0), then a causal first-order Butterworth at
        ``qd_filter_hz`` (started at rest)."""
        c = self.config
        first = np.isnan(carry.q_last).any()
        prev = q_encoder[:1] if first else carry.q_last[None]
        dq = np.diff(q_encoder, axis=0, prepend=prev) * c.rate_hz
        zi = scipy.signal.lfilter_zi(self._b, self._a)[:, None] * dq[:1] if first else carry.zi[None]
        out, zf = scipy.signal.lfilter(self._b, self._a, dq, axis=0, zi=zi)
        return out, zf[0]

    def log(self, t_true: np.ndarray, q_encoder: np.ndarray, carry: LoggerCarry, last: bool
            ) -> tuple[LoggedPiece, LoggerCarry]:
        """Lose samples, stamp the rest and (if reported) estimate q̇, for a piece of samples at the true instants
        ``t_true [N]`` [s] with encoder readings ``q_encoder [N, n]`` [rad], continuing ``carry`` (:meth:`start`
        before the first piece); ``last``: the piece ends the run (its last sample is kept)."""
        c, n = self.config, t_true.shape[0]
        m = c.dropout_max_samples
        g_drop, g_burst, g_jit = (generator_from_state(v) for v in np.split(carry.streams, len(LOGGER_STREAMS)))
        lost = np.zeros(n, dtype=bool)
        pending, active, run = carry.pending, carry.active, carry.run
        if c.dropout_prob > 0:
            starts = np.flatnonzero(g_drop.random(n) < c.dropout_prob) + 1
            lengths = g_burst.integers(1, m + 1, size=starts.size)
            mark = np.zeros(n + m + 1)
            mark[:m + 1] += carry.pending
            np.add.at(mark, starts, 1)
            np.add.at(mark, starts + lengths, -1)
            count = carry.active + np.cumsum(mark[:n])
            lost = count > 0
            idx = np.arange(n)          # overlapping bursts merge: cut each run of lost samples at the maximum
            run_start = np.maximum.accumulate(np.concatenate([[-carry.run], np.where(lost, -np.inf, idx + 1)]))[1:]
            pending, active = mark[n:], float(count[-1])
            run = float(n - run_start[-1]) if lost[-1] else 0.0
            lost &= idx - run_start < m
        if carry.seen == 0:
            lost[0] = False
        if last:
            lost[-1] = False
        keep = np.flatnonzero(~lost)
        stamps = t_true[keep].copy()
        if c.stamp_jitter_ms > 0:
            sigma = 1e-3 * c.stamp_jitter_ms
            stamps += np.clip(g_jit.normal(0.0, sigma, keep.size), -3 * sigma, 3 * sigma)
        stamp0 = float(stamps[0]) if np.isnan(carry.stamp0) and keep.size else carry.stamp0
        qd, q_last, zi = None, carry.q_last, carry.zi
        if "qd" in c.channels:
            qd_all, zi = self.robot_velocity(q_encoder, carry)
            qd, q_last = qd_all[keep], q_encoder[-1].copy()
        streams = np.concatenate([generator_state(g) for g in (g_drop, g_burst, g_jit)])
        return (LoggedPiece(keep, stamps - stamp0, qd),
                LoggerCarry(carry.seen + n, active, pending, run, stamp0, q_last, zi, streams))
