"""The robot's logger: what a real arm's log contains, as opposed to what the simulation knows.

A real arm's log (the iiwa over FRI, the LWR 4+ through its research interface, a ROS 2 bag) holds time stamps with
jitter and lost samples, the encoder ``q`` and the torque sensors' ``τ_J`` — sometimes the controller's own filtered
``q̇``, never ``q̈``. The twin's exact ``q̇``, ``q̈`` and its true sampling instants go to ``truth__*`` channels only.

The model (the ``logger:`` block of a twin config, :class:`LoggerConfig`), applied to the twin's samples at
``rate_hz`` in one vectorised pass, seeded by the twin's seed:

* **samples lost** — a burst of ``1 … dropout_max_samples`` consecutive samples is lost after any sample with
  probability ``dropout_prob`` (a late packet the host never logged), so a step of ``k + 1`` nominal periods appears
  (overlapping bursts merge, and a run of lost samples never exceeds ``dropout_max_samples``);
* **time stamps** — each kept sample is stamped ``t_true + e`` with ``e ~ N(0, stamp_jitter_ms)`` clipped to ±3σ
  (host receive time instead of the controller's sampling instant). ``3σ`` must stay below half the nominal step,
  so the stamps stay strictly increasing;
* **channels** — ``q`` and ``tau`` always; ``qd`` only when listed, as the controller's own estimate: the backward
  difference of the encoder ``q`` through a causal first-order low-pass at ``qd_filter_hz`` (computed at ``rate_hz``
  before samples are lost, as a controller does), i.e. with the phase lag a real robot's q̇ has.

:class:`RobotLogger` draws its random numbers after the sensor models, so the sensors' noise of a given sample does
not change when the logger's settings do.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import scipy.signal

from proprio.typed_yaml import load_typed

__all__ = ["LoggerConfig", "RobotLogger", "LoggedSamples"]

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


@dataclass
class LoggedSamples:
    """What :meth:`RobotLogger.log` keeps: ``keep [M]`` indices into the samples given, their ``stamps [M]`` [s] and
    the robot's own ``qd [M, n]`` [rad/s] (None unless the logger reports it)."""
    keep: np.ndarray
    stamps: np.ndarray
    qd: np.ndarray | None


class RobotLogger:
    """Applies a :class:`LoggerConfig` to samples taken at its ``rate_hz``."""

    def __init__(self, config: LoggerConfig):
        self.config = config

    def robot_velocity(self, q_encoder: np.ndarray) -> np.ndarray:
        """The controller's own q̇ [rad/s]: backward difference of the encoder ``q [N, n]`` at ``rate_hz``, then a
        causal first-order Butterworth at ``qd_filter_hz`` (started at rest on the first difference)."""
        c = self.config
        dq = np.diff(q_encoder, axis=0, prepend=q_encoder[:1]) * c.rate_hz
        b, a = scipy.signal.butter(1, float(c.qd_filter_hz), fs=c.rate_hz)
        zi = scipy.signal.lfilter_zi(b, a)[:, None] * dq[:1]
        return scipy.signal.lfilter(b, a, dq, axis=0, zi=zi)[0]

    def log(self, t_true: np.ndarray, q_encoder: np.ndarray, rng: np.random.Generator) -> LoggedSamples:
        """Lose samples, stamp the rest and (if reported) estimate q̇, for samples at the true instants ``t_true [N]``
        [s] with encoder readings ``q_encoder [N, n]`` [rad]. The first and the last sample are always kept."""
        c = self.config
        n = t_true.shape[0]
        lost = np.zeros(n, dtype=bool)
        if c.dropout_prob > 0:
            starts = np.flatnonzero(rng.random(n) < c.dropout_prob) + 1
            lengths = rng.integers(1, c.dropout_max_samples + 1, size=starts.size)
            mark = np.zeros(n + c.dropout_max_samples + 2, dtype=int)
            np.add.at(mark, starts, 1)
            np.add.at(mark, starts + lengths, -1)
            lost = np.cumsum(mark)[:n] > 0
            idx = np.arange(n)           # overlapping bursts merge: cut each run of lost samples at the maximum
            run_start = np.maximum.accumulate(np.where(lost, 0, idx + 1))
            lost &= idx - run_start < c.dropout_max_samples
            lost[[0, -1]] = False
        keep = np.flatnonzero(~lost)
        stamps = t_true[keep].copy()
        if c.stamp_jitter_ms > 0:
            sigma = 1e-3 * c.stamp_jitter_ms
            stamps += np.clip(rng.normal(0.0, sigma, keep.size), -3 * sigma, 3 * sigma)
        qd = self.robot_velocity(q_encoder)[keep] if "qd" in c.channels else None
        return LoggedSamples(keep=keep, stamps=stamps, qd=qd)
