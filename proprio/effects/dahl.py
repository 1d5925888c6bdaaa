"""The Dahl law in the reversal-travel domain, written once per step (:func:`dahl_advance`, :func:`dahl_value`) with
its batch form over a whole motion (:func:`dahl_batch`), and the pre-sliding friction that is this law on the drive.

**The law.** Between two direction reversals the torque follows the rate-independent solution of
``dτ/dr = σ(1 − τ/(d·L))``: ``τ = d·L + (τ_rev − d·L)·exp(−|r| / ρ)`` with ``d`` the direction of motion (the
Schmitt trigger of :func:`proprio.reversals.motion_direction`), ``r`` the travel since the last reversal (from the
extremum reached before it), ``L`` the level it saturates at [N·m], ``ρ`` [rad] a third of the travel after which it is
within 5 % of ``L`` and ``τ_rev`` the value carried over the reversal (0 in the virgin state). The per-step form keeps
the reversal state explicitly (:class:`DahlState`); the batch form segments the whole motion at once
(:func:`proprio.reversals.reversal_travel`) and runs the recursion of the carried values once per reversal (a numba
kernel) — the same recursion, so the two agree to rounding (tests).

Two effects are this law: the torque sensor's hysteresis (:class:`proprio.effects.Hysteresis`, a strain gauge's loop
over degrees of travel) and the drive's pre-sliding friction (:class:`PreSliding`, the gear and bearings' elastic
micro-displacement before gross sliding, over tenths of a degree). In a torque they are the same function of ``r``,
which is why the diagnosis offers one of them per kind of τ (:mod:`proprio.diagnosis.candidates.drive`): the gauge's
loop for a link-side torque sensor, pre-sliding for drive torques (no gauge there).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from proprio.effects.base import INF, TINY, JointEffect, motion_reversal_travel
from proprio.reversals import ReversalTravel
from proprio.signals import MotionSignals

__all__ = ["DahlState", "DahlCarry", "DahlEffect", "dahl_start", "dahl_advance", "dahl_value", "dahl_batch",
           "PreSliding", "MAX_PRESLIDING_TRAVEL"]

MAX_PRESLIDING_TRAVEL = math.radians(2.0)
"""Upper bound of ``presliding_travel`` [rad]: pre-sliding is the gear's micro-displacement (well under a degree at
the joint on harmonic and cycloid drives); a loop over several degrees is not friction before sliding."""


@dataclass(frozen=True)
class DahlState:
    """Per-joint reversal state of the per-step law (each ``[n]``): direction ``d`` ∈ {−1, 0, +1}, running extrema
    ``hi``/``lo`` [rad] of q in the current segment, the segment's ``anchor`` [rad], the value carried over the last
    reversal ``tau_rev`` [N·m] and the level of the previous sample ``level_prev`` [N·m]."""
    d: np.ndarray
    hi: np.ndarray
    lo: np.ndarray
    anchor: np.ndarray
    tau_rev: np.ndarray
    level_prev: np.ndarray

    def vector(self) -> np.ndarray:
        """``[6n]``: the fields in declaration order (a Drake discrete state)."""
        return np.concatenate([self.d, self.hi, self.lo, self.anchor, self.tau_rev, self.level_prev])

    @classmethod
    def from_vector(cls, v: np.ndarray) -> "DahlState":
        return cls(*np.split(np.asarray(v, dtype=float), 6))


def _raw_direction(qd: np.ndarray, eps: np.ndarray) -> np.ndarray:
    return np.where(qd > eps, 1.0, np.where(qd < -eps, -1.0, 0.0))


def dahl_start(q: np.ndarray, qd: np.ndarray, level: np.ndarray, eps: np.ndarray) -> DahlState:
    """The state *before* the first sample ``(q, q̇)`` [rad, rad/s] ``[n]``: the first sample then starts the first
    segment at q without a reversal (virgin state, ``τ_rev = 0``); ``eps`` the reversal velocity [rad/s]."""
    q = np.asarray(q, dtype=float)
    return DahlState(_raw_direction(qd, eps), q.copy(), q.copy(), q.copy(), np.zeros_like(q),
                     np.broadcast_to(level, q.shape).astype(float))


def dahl_advance(st: DahlState, q: np.ndarray, qd: np.ndarray, level: np.ndarray, rho: np.ndarray,
                 eps: np.ndarray) -> DahlState:
    """The state after taking in one sample ``(q, q̇)`` ``[n]`` with its level ``L`` [N·m] (``ρ`` [rad], ``eps``
    [rad/s]): a reversal carries the law of the ending segment, evaluated at its extremum, into ``τ_rev``."""
    raw = _raw_direction(qd, eps)
    d = np.where(raw != 0, raw, st.d)
    flip = (d != st.d) & (st.d != 0)
    new_anchor = np.where(st.d > 0, st.hi, st.lo)
    target = st.d * st.level_prev
    carried = target + (st.tau_rev - target) * np.exp(-np.abs(new_anchor - st.anchor) / rho)
    return DahlState(d, np.where(flip, q, np.maximum(st.hi, q)), np.where(flip, q, np.minimum(st.lo, q)),
                     np.where(flip, new_anchor, st.anchor), np.where(flip, carried, st.tau_rev),
                     np.broadcast_to(level, d.shape).astype(float))


def dahl_value(st: DahlState, q: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """The law's torque [N·m] ``[n]`` at ``q`` with the state already advanced by this sample."""
    d_level = st.d * st.level_prev
    return d_level + (st.tau_rev - d_level) * np.exp(-np.abs(q - st.anchor) / rho)


@dataclass(frozen=True)
class DahlCarry:
    """What the batch law carries from one piece of a motion into the next (each ``[n]``): the value carried into
    the current segment ``tau_rev`` [N·m] and the level of the last sample ``level_prev`` [N·m] (with the reversal
    state :class:`proprio.reversals.ReversalCarry`)."""
    tau_rev: np.ndarray
    level_prev: np.ndarray

    @classmethod
    def virgin(cls, n: int) -> "DahlCarry":
        return cls(np.zeros(n), np.zeros(n))

    def vector(self) -> np.ndarray:
        return np.concatenate([self.tau_rev, self.level_prev])

    @classmethod
    def from_vector(cls, v: np.ndarray) -> "DahlCarry":
        return cls(*np.split(np.asarray(v, dtype=float), 2))


@numba.njit(cache=True)
def _carried_kernel(starts, anchors, seg_dirs, offsets, level, rho, tau_rev0, level_prev0):  # pragma: no cover
    """The value carried into each segment (flat, at ``offsets[j]`` per joint): the recursion of
    :func:`dahl_advance` at each reversal, ``τ_rev ← e·τ_rev + (1 − e)·d·L_end`` with ``e = exp(−|Δanchor| / ρ)``."""
    out = np.empty(anchors.size)
    for j in range(offsets.size - 1):
        o, m = offsets[j], offsets[j + 1] - offsets[j]
        x = tau_rev0[j]
        out[o] = x
        for k in range(m - 1):
            last = starts[o + k + 1] - 1                       # last sample of segment k (-1: it ended before)
            lv = level_prev0[j] if last < 0 else level[last, j]
            e = np.exp(-abs(anchors[o + k + 1] - anchors[o + k]) / rho[j])
            x = e * x + (1.0 - e) * seg_dirs[o + k] * lv
            out[o + k + 1] = x
    return out


def dahl_batch(rt: ReversalTravel, level: np.ndarray, rho: np.ndarray, carry: DahlCarry | None = None
               ) -> tuple[np.ndarray, DahlCarry]:
    """The law over a whole motion ``[N,n]`` [N·m] and its end state: ``rt`` its reversal travel, ``level [N,n]``
    [N·m] per sample, ``rho [n]`` [rad], ``carry`` the state at the end of the previous piece (``rt`` segmented with
    its reversal carry; default: the virgin state). Per joint, the value carried into each segment is the ending
    segment's law at the next anchor with the level of its last sample (the recursion of :func:`dahl_advance`, a
    numba kernel over the reversals); within a segment the law is vectorised over samples and joints."""
    n_s, n = rt.r.shape
    c = DahlCarry.virgin(n) if carry is None else carry
    level = np.ascontiguousarray(np.broadcast_to(level, (n_s, n)), dtype=float)
    rho = np.broadcast_to(np.asarray(rho, dtype=float), (n,))
    sizes = np.array([st.size for st in rt.starts])
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    tau_rev = _carried_kernel(np.concatenate(rt.starts), np.concatenate(rt.anchors),
                              np.concatenate(rt.seg_direction), offsets, level, np.ascontiguousarray(rho),
                              np.asarray(c.tau_rev, dtype=float), np.asarray(c.level_prev, dtype=float))
    local = rt.segment - (rt.segment[-1] - (sizes - 1))                  # segment index within this piece
    d_level = rt.direction * level
    out = d_level + (tau_rev[offsets[:-1] + local] - d_level) * np.exp(-np.abs(rt.r) / rho)
    return out, DahlCarry(tau_rev[offsets[1:] - 1], level[-1].copy())


class DahlEffect(JointEffect):
    """An effect that is the Dahl law (module docstring): :meth:`torque` over a whole motion and
    :meth:`torque_carried` over a piece of it with the carried state. Subclasses give the level [N·m] per sample
    (:meth:`dahl_level`) and ``ρ`` [rad] (:attr:`rho`)."""

    @property
    def rho(self) -> np.ndarray:
        raise NotImplementedError

    def dahl_level(self, s: MotionSignals) -> np.ndarray:
        """The level ``L [N,n]`` [N·m] the law saturates at, per sample."""
        raise NotImplementedError

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        return self.torque_carried(s, travel or motion_reversal_travel(s, self.reversal_velocity))[0]

    def torque_carried(self, s: MotionSignals, travel: ReversalTravel, carry: DahlCarry | None = None
                       ) -> tuple[np.ndarray, DahlCarry]:
        """The torque ``[N,n]`` N·m over ``s`` (segmented as ``travel``, with its reversal carry) continuing the
        state ``carry`` of the motion's previous piece, and the state at its end."""
        self._check_n(s)
        return dahl_batch(travel, self.dahl_level(s), self.rho, carry)


class PreSliding(DahlEffect):
    """Pre-sliding friction of the drive: a rate-independent Dahl law in the travel since the last reversal
    (module docstring), ``τ_ps = d·F + (τ_rev − d·F)·exp(−3|r| / r_ps)`` [N·m] — after a reversal the friction
    turns over within ``r_ps`` of joint travel whatever the speed, where the velocity law of
    :mod:`proprio.friction_law` (``tanh(q̇/v_s)``) turns over within a band of speed. A real drive's low-speed and
    near-reversal error (the gap concentrated within a degree of reversals) is this law.

    Parameters ``level`` F [N·m] (the friction it saturates at), ``presliding_travel`` r_ps [rad] (YAML
    ``presliding_travel_deg``; within 5 % of F after it; at most :data:`MAX_PRESLIDING_TRAVEL`); setting
    ``reversal_velocity`` [rad/s] (deadband of the reversal detection). Dissipative in the large (a loop), it acts
    on the links like the other link-side friction (the twin's :class:`~proprio.systems.joint_drive.JointDrive`
    keeps its reversal state as Drake discrete state, :meth:`step`).
    """
    name = "presliding"
    place = "link"
    linear = False
    parameters = {"level": (0.0, 0.0, INF), "presliding_travel": (math.radians(0.5), TINY, MAX_PRESLIDING_TRAVEL)}
    settings = {"reversal_velocity": (2e-3, 0.0, INF)}

    @property
    def rho(self) -> np.ndarray:
        """``ρ = r_ps / 3`` [rad] per joint."""
        return self.presliding_travel / 3.0

    def dahl_level(self, s: MotionSignals) -> np.ndarray:
        return np.broadcast_to(self.level, s.q.shape)

    def start(self, q: np.ndarray, qd: np.ndarray) -> DahlState:
        """The per-step state before the first sample ``(q, q̇)`` ``[n]`` (:func:`dahl_start`)."""
        return dahl_start(q, qd, self.level, self.reversal_velocity)

    def step(self, st: DahlState, q: np.ndarray, qd: np.ndarray) -> tuple[DahlState, np.ndarray]:
        """One sample of the per-step law: the state advanced by ``(q, q̇)`` ``[n]`` and the torque ``[n]`` N·m."""
        new = dahl_advance(st, q, qd, self.level, self.rho, self.reversal_velocity)
        return new, dahl_value(new, q, self.rho)
