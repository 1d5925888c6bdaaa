"""The robot's logger: what a real arm's log contains, as opposed to what the simulation knows.

A real arm's log (the iiwa over FRI, the LWR 4+ through its research interface, a ROS 2 bag) holds time stamps with
jitter and lost samples, the encoder ``q`` and the torque sensors' ``τ_J`` — sometimes the controller's own filtered
``q̇``, never ``q̈``. The twin's exact ``q̇``, ``q̈`` and its true sampling instants go to ``truth__*`` channels only.

The model (the ``logger:`` block of a twin config, :class:`LoggerConfig`) is the Drake System
:class:`RobotLoggerSystem` in the twin's Diagram, the last stage of its measurement chain: it takes the encoder's q and
the torque sensor's τ of each time step (in blocks) and decides sample by sample, seeded by the twin's seed:

* **sampling** — the samples at ``rate_hz``: the time step nearest to each ``m / rate_hz`` (150 Hz → 6/7 ms steps
  like the iiwa; :func:`sample_steps`);
* **samples lost** — a burst of ``1 … dropout_max_samples`` consecutive samples is lost after any sample with
  probability ``dropout_prob`` (a late packet the host never logged), so a step of ``k + 1`` nominal periods appears
  (overlapping bursts merge, and a run of lost samples never exceeds ``dropout_max_samples``); the first and the last
  sample are always kept;
* **time stamps** — each kept sample is stamped ``t_true + e`` with ``e ~ N(0, stamp_jitter_ms)`` clipped to ±3σ
  (host receive time instead of the controller's sampling instant). ``3σ`` must stay below half the nominal step,
  so the stamps stay strictly increasing;
* **channels** — ``q`` and ``tau`` always; ``qd`` only when listed, as the controller's own estimate: the backward
  difference of the encoder ``q`` through a causal first-order low-pass at ``qd_filter_hz`` (computed at ``rate_hz``
  before samples are lost, as a controller does), i.e. with the phase lag a real robot's q̇ has.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import scipy.signal
from pydrake.systems.framework import Context

from proprio.systems.sensors import BlockSystem
from proprio.typed_yaml import load_typed

__all__ = ["LoggerConfig", "RobotLoggerSystem", "sample_steps"]

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


def sample_steps(n_steps: int, time_step: float, rate_hz: float) -> np.ndarray:
    """Indices of the ``n_steps`` time steps of ``time_step`` [s] sampled at ``rate_hz`` [Hz] (nearest step)."""
    if abs(rate_hz * time_step - 1.0) < 1e-9:
        return np.arange(n_steps)
    t_want = np.arange(0.0, n_steps * time_step, 1.0 / rate_hz)
    return np.unique(np.minimum(np.round(t_want / time_step).astype(int), n_steps - 1))


class RobotLoggerSystem(BlockSystem):
    """The robot's logger (module docstring) for ``n`` joints on a twin of ``n_steps`` time steps of ``time_step``
    [s] from ``start_time`` [s], block by block (:class:`~proprio.systems.sensors.BlockSystem`; its draws are stream 2
    of ``seed``).

    Input ports ``q_measured`` [B·n] rad (the encoder's block) and ``tau_measured`` [B·n] N·m (the torque sensor's).
    Output port ``record`` [B·(4 + 2n (+ n))]: per time step ``[taken, kept, stamp [s], t_true [s], q [n], τ [n]
    (, q̇ [n] when the robot reports it)]`` for the block read at this time; ``taken`` = 1 when that step was a
    sample at ``rate_hz``, ``kept`` = 1 when it was not lost. Discrete state: the next sample's index, the last
    sample a started burst covers, the position of the last sample in a run of covered ones, the previous encoder q
    and the q̇ filter's state.
    """

    def __init__(self, n: int, config: LoggerConfig, time_step: float, n_steps: int, start_time: float = 0.0,
                 block_steps: int = 1, seed: int = 0):
        super().__init__(block_steps, time_step, start_time, seed, stream=2)
        self.n, self.config = n, config
        self.steps = sample_steps(n_steps, time_step, config.rate_hz)
        self._qd = "qd" in config.channels
        if self._qd:
            self._ba = scipy.signal.butter(1, float(config.qd_filter_hz), fs=config.rate_hz)
        self._q = self.DeclareVectorInputPort("q_measured", self.block_steps * n)
        self._tau = self.DeclareVectorInputPort("tau_measured", self.block_steps * n)
        self._inner = self.DeclareDiscreteState(np.concatenate([[0.0, -1.0, -1.0], np.zeros(2 * n)]))
        self._width = 4 + 2 * n + (n if self._qd else 0)
        self._block = self.declare_block(self._calc_block, self._inner)
        self.DeclareVectorOutputPort("record", self.block_steps * self._width,
                                     lambda context, out: out.SetFromVector(self._block.Eval(context)[1]),
                                     prerequisites_of_calc={self._block.ticket()})

    def _calc_block(self, context: Context) -> tuple[np.ndarray, np.ndarray]:
        c, n, b = self.config, self.n, self.block_steps
        k, t = self.block(context)
        inner = context.get_discrete_state(self._inner).value()
        first, pending, pos = int(inner[0]), inner[1], inner[2]
        idx = np.minimum(np.searchsorted(self.steps, k), self.steps.size - 1)
        taken = self.steps[idx] == k
        i = idx[taken]                                              # sample indices, first, first + 1, ...
        rng = self.rng(k)
        u, z = rng.random((b, 2))[taken], rng.standard_normal(b)[taken]
        q = self._q.Eval(context).reshape(b, n)[taken]
        # lost samples: bursts started after sample i cover i + 1 ... i + L, L = 1 + ⌊u·max⌋
        cover = np.where(u[:, 0] < c.dropout_prob, i + 1 + (u[:, 1] * c.dropout_max_samples).astype(int), -1)
        before = np.maximum(pending, np.concatenate([[-1], np.maximum.accumulate(cover)[:-1]]))
        covered = i <= before
        count = np.arange(i.size)
        last_free = np.maximum.accumulate(np.where(~covered, count, -(pos + 2.0)))
        run_pos = np.where(covered, count - last_free - 1, -1.0)     # position in the run of covered samples
        lost = covered & (run_pos < c.dropout_max_samples) & (i > 0) & (i < self.steps.size - 1)
        stamps = t[taken].copy()
        if c.stamp_jitter_ms > 0:
            sigma = 1e-3 * c.stamp_jitter_ms
            stamps += np.clip(sigma * z, -3 * sigma, 3 * sigma)
        record = np.zeros((b, self._width))
        record[taken, 0], record[taken, 1], record[taken, 2], record[taken, 3] = 1.0, ~lost, stamps, t[taken]
        record[taken, 4:4 + n] = q
        record[taken, 4 + n:4 + 2 * n] = self._tau.Eval(context).reshape(b, n)[taken]
        q_prev, zf = inner[3:3 + n], inner[3 + n:]
        if i.size:
            if self._qd:                                             # backward difference, first-order low-pass
                dq = np.diff(q, axis=0, prepend=(q[:1] if first == 0 else q_prev[None])) * c.rate_hz
                y, zf = scipy.signal.lfilter(*self._ba, dq, axis=0, zi=zf[None])
                record[taken, 4 + 2 * n:] = y
                zf = zf[0]
            q_prev = q[-1]
            pending = max(pending, float(cover.max()))
            pos = run_pos[-1]
        return np.concatenate([[first + i.size, pending, pos], q_prev, zf]), record.ravel()
