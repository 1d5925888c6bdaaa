"""Torque-sensor effects that depend on the reversal travel r: hysteresis and lost motion.

Each law is written once, as a scan with state: :meth:`Hysteresis.scan` ``(x0, q, q̇, τ) → (x_end, contribution)``
over samples ``[N, n]`` from the effect's state ``x0`` (:meth:`initial_state`: the reversal tracker of
:func:`proprio.reversals.reversal_scan` plus, for the hysteresis, the value carried at the last reversal and the
last sample's saturation). The batch form :meth:`~JointEffect.torque` is the scan of a whole motion from rest (the
diagnosis, the fits, the offline benchmark); the twin's torque-sensor System
(:class:`proprio.systems.sensors.TorqueSensorSystem`) keeps ``x`` as Drake discrete state and scans block after
block of time steps (one step is a block of one). Both agree to rounding (tests: 1e-12 N·m).
"""
from __future__ import annotations

import math

import numpy as np

from proprio.effects.base import INF, TINY, JointEffect, affine_scan
from proprio.reversals import ReversalTravel, reversal_scan, reversal_start
from proprio.signals import MotionSignals

__all__ = ["Hysteresis", "LostMotion", "MAX_LOAD_GAIN"]

MAX_LOAD_GAIN = 0.1
"""Upper bound of ``load_gain`` [–]: the loop amplitude grows by at most 10 % of the load torque (the calibrated twin
has 2 %, Fig. 2.5's gravity-loaded joints); a fit beyond it is a light joint's loop taken for a load law."""

class Hysteresis(JointEffect):
    """Torque-sensor hysteresis vs. joint travel since the last reversal (thesis §2.1, Fig. 2.5).

    A Dahl law in the travel domain (the rate-independent solution of ``dτ/dr = σ(1 − τ/(d·τ_sat))``):
    ``τ_h = d·τ_sat + (τ_rev − d·τ_sat)·exp(−|r| / ρ)`` with ``d`` the segment's direction, ``r`` the reversal
    travel and ``τ_rev`` the value at the reversal (continuous across reversals; a fresh start is the virgin
    state τ_rev = 0). ``ρ = saturation_travel / 3`` so τ_h is within 5 % of saturation after ``saturation_travel``
    (6° → slope after 6° is e⁻³ ≈ 5 % of the slope at the reversal). Dahl was chosen over Bouc–Wen (more
    parameters, same loop shape for this purpose) and Preisach/Maxwell-slip (many elements) because two
    parameters per joint reproduce the thesis' loop and can be fitted from one triangular experiment.

    Parameters ``saturation`` τ_sat [N·m], ``load_gain`` [–] (τ_sat grows by ``load_gain·|τ|``, for the
    gravity-loaded joints 2/4), ``saturation_travel`` [rad] (YAML ``saturation_travel_deg``); setting
    ``reversal_velocity`` [rad/s] (deadband of the reversal detection).
    """
    name = "hysteresis"
    place = "sensor"
    linear = False
    parameters = {"saturation": (0.0, 0.0, INF), "load_gain": (0.0, 0.0, MAX_LOAD_GAIN),
                  "saturation_travel": (math.radians(6.0), TINY, INF)}
    settings = {"reversal_velocity": (2e-3, 0.0, INF)}

    state_size = 7          # per joint: the reversal tracker (REVERSAL_FIELDS), τ_rev, τ_sat of the last sample

    @staticmethod
    def loop(d_sat: np.ndarray, tau_rev: np.ndarray, travel: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """The Dahl law in the travel domain [N·m]: ``d·τ_sat + (τ_rev − d·τ_sat)·exp(−|r|/ρ)``."""
        return d_sat + (tau_rev - d_sat) * np.exp(-np.abs(travel) / rho)

    @staticmethod
    def carry(span: np.ndarray, target: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The value carried into the next segment as the affine map ``τ_rev' = a·τ_rev + b`` of the one carried
        into the segment that ended (the loop evaluated at its end, ``span`` = anchor travel [rad], ``target`` =
        its ``d·τ_sat``): returns ``(a, b)``."""
        a = np.exp(-np.abs(span) / rho)
        return a, (1.0 - a) * target

    def _saturation(self, tau: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
        """τ_sat = saturation + load_gain·|τ| [N·m]."""
        if not np.any(self.load_gain):
            return np.broadcast_to(self.saturation, shape)
        if tau is None:
            raise ValueError(f"{self.name}: load_gain is set, so MotionSignals.tau (the transmitted torque) is "
                             "required")
        return self.saturation + self.load_gain * np.abs(tau)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        x0 = self.initial_state(s.q[0], s.qd[0], None if s.tau is None else s.tau[0])
        return self.scan(x0, s.q, s.qd, s.tau, travel)[1]

    def initial_state(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None) -> np.ndarray:
        """The state ``[7n]`` before a first sample ``(q, q̇, τ)`` ``[n]``: at rest, virgin (τ_rev = 0)."""
        return np.concatenate([reversal_start(q, qd, self.reversal_velocity), np.zeros(self.n),
                               self._saturation(tau, q.shape)])

    def scan(self, x0: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None,
             travel: ReversalTravel | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The law over samples ``q, q̇, τ`` ``[N, n]`` from state ``x0`` ``[7n]`` (module docstring): returns the
        state after the last sample and the contribution ``[N, n]`` N·m. ``travel``: the reversal scan of the same
        samples from the same state, if already computed."""
        n = self.n
        rt = travel or reversal_scan(x0[:5 * n], q, qd, self.reversal_velocity)
        sat = self._saturation(tau, q.shape)
        sat_ext = np.vstack([x0[6 * n:], sat])                   # [the last sample's saturation; samples]
        rho = self.saturation_travel / 3.0
        out, tau_end = np.empty_like(q), np.empty(n)
        for j in range(n):
            anc, sd = rt.anchors[j], rt.seg_direction[j]
            ends = rt.starts[j][1:]                           # last sample of each ended segment, in sat_ext rows
            a, b = self.carry(anc[1:] - anc[:-1], sd[:-1] * sat_ext[ends, j], rho[j])
            tau_rev = affine_scan(a, b, x0[5 * n + j])
            out[:, j] = self.loop(rt.direction[:, j] * sat[:, j], tau_rev[rt.segment[:, j]], rt.r[:, j], rho[j])
            tau_end[j] = tau_rev[-1]
        return np.concatenate([rt.end, tau_end, sat[-1]]), out


class LostMotion(JointEffect):
    """Lost motion after a reversal: for ≈``window`` of travel the direction-dependent part of τ has not flipped.

    ``τ_lm = −d·c·A·exp(−(|r|/W)⁶)`` with ``d`` the new direction, ``r`` the reversal travel, ``A = amplitude +
    load_gain·|τ|`` the direction-dependent torque level that lags, ``c = 2`` after a reversal (the level flips from
    −dA to +dA) and ``c = 1`` when starting from standstill. With ``A`` equal to the Coulomb level the measured
    torque "barely changes" within the window (thesis §4 intro: absent changes of torque within ≈1° after
    reversals), then the full flip appears; the profile is flat (< 2 % change) up to W/2 and has released half
    of the flip at 0.94 W.

    Parameters ``amplitude`` A [N·m], ``load_gain`` [–], ``window`` W [rad] (YAML ``window_deg``); setting
    ``reversal_velocity`` [rad/s].
    """
    name = "lost_motion"
    place = "sensor"
    linear = False
    parameters = {"amplitude": (0.0, 0.0, INF), "load_gain": (0.0, 0.0, MAX_LOAD_GAIN),
                  "window": (math.radians(1.0), TINY, INF)}
    settings = {"reversal_velocity": (2e-3, 0.0, INF)}

    state_size = 5          # per joint: the reversal tracker (REVERSAL_FIELDS)

    def lag(self, direction: np.ndarray, reversed_: np.ndarray, tau: np.ndarray | None, travel: np.ndarray
            ) -> np.ndarray:
        """The law [N·m]: ``−d·(1 + reversed)·A·exp(−(|r|/W)⁶)`` with ``A = amplitude + load_gain·|τ|``."""
        if np.any(self.load_gain) and tau is None:
            raise ValueError(f"{self.name}: load_gain is set, so MotionSignals.tau (the transmitted torque) is "
                             "required")
        amp = self.amplitude + (self.load_gain * np.abs(tau) if np.any(self.load_gain) else 0.0)
        return -direction * (1.0 + reversed_) * amp * np.exp(-(np.abs(travel) / self.window) ** 6)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        return self.scan(self.initial_state(s.q[0], s.qd[0], None), s.q, s.qd, s.tau, travel)[1]

    def initial_state(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None) -> np.ndarray:
        """The state ``[5n]`` before a first sample ``(q, q̇)`` ``[n]``: at rest."""
        return reversal_start(q, qd, self.reversal_velocity)

    def scan(self, x0: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None,
             travel: ReversalTravel | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The law over samples ``q, q̇, τ`` ``[N, n]`` from state ``x0`` ``[5n]``: the state after the last sample and
        the contribution ``[N, n]`` N·m (c = 2 after a reversal in these samples or before them, else 1)."""
        rt = travel or reversal_scan(x0, q, qd, self.reversal_velocity)
        reversed_ = np.where(rt.segment > 0, 1.0, x0[self.n:2 * self.n])
        return rt.end, self.lag(rt.direction, reversed_, tau, rt.r)
