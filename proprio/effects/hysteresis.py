"""Torque-sensor effects that depend on the reversal travel r: hysteresis and lost motion.

Each law is written once and evaluated in two forms that call the same functions:

* the batch form :meth:`~JointEffect.torque` over a whole motion ``[N, n]`` (the diagnosis, the fits, the offline
  benchmark), with the reversal segmentation of :func:`proprio.reversals.reversal_travel`;
* the per-step form :meth:`step` ``(x, q, q̇, τ) → (x', contribution)`` on one sample ``[n]`` with the effect's state
  ``x`` (:meth:`initial_state`, :attr:`state_size`): the online reversal tracker (:func:`reversal_advance`) plus,
  for the hysteresis, the value carried at the last reversal. The twin's torque-sensor System
  (:class:`proprio.systems.sensors.TorqueSensorSystem`) keeps ``x`` as Drake discrete state and calls :meth:`step`
  every time step; both forms agree to rounding (tests: 1e-12 N·m).
"""
from __future__ import annotations

import math

import numpy as np

from proprio.effects.base import INF, TINY, JointEffect, affine_scan
from proprio.reversals import ReversalTravel, reversal_travel
from proprio.signals import MotionSignals

__all__ = ["Hysteresis", "LostMotion", "MAX_LOAD_GAIN", "REVERSAL_FIELDS", "reversal_start", "reversal_advance"]

MAX_LOAD_GAIN = 0.1
"""Upper bound of ``load_gain`` [–]: the loop amplitude grows by at most 10 % of the load torque (the calibrated twin
has 2 %, Fig. 2.5's gravity-loaded joints); a fit beyond it is a light joint's loop taken for a load law."""

REVERSAL_FIELDS = ("d", "reversed", "hi", "lo", "anchor")
"""The online reversal tracker's state per joint, packed ``[5·n]`` in this order: direction d ∈ {−1, 0, +1}, has
reversed (0/1), running max / min of q in the current segment [rad], the segment's anchor [rad]."""


def _direction(qd: np.ndarray, reversal_velocity: np.ndarray) -> np.ndarray:
    """Raw direction of one sample ``[n]``: ±1 outside the ``reversal_velocity`` band [rad/s], 0 inside."""
    return np.where(qd > reversal_velocity, 1.0, np.where(qd < -reversal_velocity, -1.0, 0.0))


def reversal_start(q: np.ndarray, qd: np.ndarray, reversal_velocity: np.ndarray) -> np.ndarray:
    """The tracker's state *before* the first sample ``(q, q̇)`` ``[n]``: the first sample then starts segment 0 at
    q[0] without a reversal, as :func:`~proprio.reversals.reversal_travel` does."""
    return np.concatenate([_direction(qd, reversal_velocity), np.zeros_like(q), q, q, q])


def reversal_advance(x: np.ndarray, q: np.ndarray, qd: np.ndarray, reversal_velocity: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Take in one sample ``(q, q̇)`` ``[n]``: returns the new state, the reversal flags ``[n]`` (a reversal starts a
    new segment at this sample) and the previous anchor ``[n]`` (the segment that ended started there). The online
    form of :func:`~proprio.reversals.reversal_travel`: a Schmitt trigger on q̇, the anchor of a new segment is the
    extremum of q reached in the one that ended."""
    n = q.shape[0]
    d0, rev, hi, lo, anchor = (x[k * n:(k + 1) * n] for k in range(5))
    raw = _direction(qd, reversal_velocity)
    d = np.where(raw != 0, raw, d0)
    flip = (d != d0) & (d0 != 0)
    new_anchor = np.where(d0 > 0, hi, lo)
    state = np.concatenate([d, np.where(flip, 1.0, rev), np.where(flip, q, np.maximum(hi, q)),
                            np.where(flip, q, np.minimum(lo, q)), np.where(flip, new_anchor, anchor)])
    return state, flip, anchor


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
            raise ValueError(f"{self.name}: load_gain is set, so the transmitted torque is required")
        return self.saturation + self.load_gain * np.abs(tau)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        rt = travel or reversal_travel(s.q, s.qd, self.reversal_velocity)
        sat = self._saturation(s.tau, s.q.shape)
        rho = self.saturation_travel / 3.0
        out = np.empty_like(s.q)
        for j in range(self.n):
            st, anc, sd = rt.starts[j], rt.anchors[j], rt.seg_direction[j]
            ends = np.concatenate([st[1:] - 1, [s.q.shape[0] - 1]])
            a, b = self.carry(anc[1:] - anc[:-1], sd[:-1] * sat[ends[:-1], j], rho[j])
            tau_rev = affine_scan(a, b, 0.0)
            out[:, j] = self.loop(rt.direction[:, j] * sat[:, j], tau_rev[rt.segment[:, j]], rt.r[:, j], rho[j])
        return out

    def initial_state(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None) -> np.ndarray:
        """The per-step state ``[7n]`` before the first sample (virgin: τ_rev = 0)."""
        return np.concatenate([reversal_start(q, qd, self.reversal_velocity), np.zeros(self.n),
                               self._saturation(tau, q.shape)])

    def step(self, x: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray]:
        """One sample ``(q, q̇, τ_J)`` ``[n]``: ``(state after it, contribution [N·m])`` (module docstring)."""
        n = self.n
        rho = self.saturation_travel / 3.0
        rev, tau_rev, sat_prev = x[:5 * n], x[5 * n:6 * n], x[6 * n:]
        rev_new, flip, anchor = reversal_advance(rev, q, qd, self.reversal_velocity)
        a, b = self.carry(rev_new[4 * n:] - anchor, rev[:n] * sat_prev, rho)
        tau_rev = np.where(flip, a * tau_rev + b, tau_rev)
        sat = self._saturation(tau, q.shape)
        out = self.loop(rev_new[:n] * sat, tau_rev, q - rev_new[4 * n:], rho)
        return np.concatenate([rev_new, tau_rev, sat]), out


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
            raise ValueError(f"{self.name}: load_gain is set, so the transmitted torque is required")
        amp = self.amplitude + (self.load_gain * np.abs(tau) if np.any(self.load_gain) else 0.0)
        return -direction * (1.0 + reversed_) * amp * np.exp(-(np.abs(travel) / self.window) ** 6)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        rt = travel or reversal_travel(s.q, s.qd, self.reversal_velocity)
        return self.lag(rt.direction, (rt.segment > 0).astype(float), s.tau, rt.r)

    def initial_state(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None) -> np.ndarray:
        """The per-step state ``[5n]`` before the first sample."""
        return reversal_start(q, qd, self.reversal_velocity)

    def step(self, x: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray]:
        """One sample ``(q, q̇, τ_J)`` ``[n]``: ``(state after it, contribution [N·m])`` (module docstring)."""
        n = self.n
        rev, _, _ = reversal_advance(x, q, qd, self.reversal_velocity)
        return rev, self.lag(rev[:n], rev[n:2 * n], tau, q - rev[4 * n:])


