"""The Dahl law in the reversal-travel domain, written once per step (:func:`dahl_advance`, :func:`dahl_value`) with
its batch form over a whole motion (:func:`dahl_batch`), and the pre-sliding friction that is this law on the drive.

**The law.** Between two direction reversals the torque follows the rate-independent solution of
``dτ/dr = σ(1 − τ/(d·L))``: ``τ = d·L + (τ_rev − d·L)·exp(−|r| / ρ)`` with ``d`` the direction of motion (the
Schmitt trigger of :func:`proprio.reversals.motion_direction`), ``r`` the travel since the last reversal (from the
extremum reached before it), ``L`` the level it saturates at [N·m], ``ρ`` [rad] a third of the travel after which it is
within 5 % of ``L`` and ``τ_rev`` the value carried over the reversal (0 in the virgin state). The per-step form keeps
the reversal state explicitly (:class:`DahlState`); the batch form segments the whole motion at once
(:func:`proprio.reversals.reversal_travel`) and solves the recursion of the carried values with a prefix scan
(:func:`proprio.effects.base.affine_scan`) — the same recursion, so the two agree to rounding (tests).

Two effects are this law: the torque sensor's hysteresis (:class:`proprio.effects.Hysteresis`, a strain gauge's loop
over degrees of travel) and the drive's pre-sliding friction (:class:`PreSliding`, the gear and bearings' elastic
micro-displacement before gross sliding, over tenths of a degree). In a torque they are the same function of ``r``,
which is why the diagnosis offers one of them per kind of τ (:mod:`proprio.diagnosis.candidates.drive`): the gauge's
loop for a link-side torque sensor, pre-sliding for drive torques (no gauge there).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from proprio.effects.base import INF, TINY, JointEffect, affine_scan, motion_reversal_travel
from proprio.reversals import ReversalTravel
from proprio.signals import MotionSignals

__all__ = ["DahlState", "dahl_start", "dahl_advance", "dahl_value", "dahl_batch", "PreSliding", "MAX_PRESLIDING_TRAVEL"]

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


def dahl_batch(rt: ReversalTravel, level: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """The law over a whole motion ``[N,n]`` [N·m]: ``rt`` its reversal travel, ``level [N,n]`` [N·m] per sample,
    ``rho [n]`` [rad]. Per joint, the value carried into each segment is the ending segment's law at the next anchor
    with the level of its last sample (the recursion of :func:`dahl_advance`, solved by a prefix scan)."""
    n_s, n = rt.r.shape
    out = np.empty((n_s, n))
    for j in range(n):                                                   # loop over joints only
        st, anc, sd = rt.starts[j], rt.anchors[j], rt.seg_direction[j]
        ends = np.concatenate([st[1:] - 1, [n_s - 1]])
        e = np.exp(-np.abs(anc[1:] - anc[:-1]) / rho[j])
        target = sd[:-1] * level[ends[:-1], j]
        tau_rev = affine_scan(e, (1.0 - e) * target, 0.0)
        d_level = rt.direction[:, j] * level[:, j]
        out[:, j] = d_level + (tau_rev[rt.segment[:, j]] - d_level) * np.exp(-np.abs(rt.r[:, j]) / rho[j])
    return out


class PreSliding(JointEffect):
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

    def start(self, q: np.ndarray, qd: np.ndarray) -> DahlState:
        """The per-step state before the first sample ``(q, q̇)`` ``[n]`` (:func:`dahl_start`)."""
        return dahl_start(q, qd, self.level, self.reversal_velocity)

    def step(self, st: DahlState, q: np.ndarray, qd: np.ndarray) -> tuple[DahlState, np.ndarray]:
        """One sample of the per-step law: the state advanced by ``(q, q̇)`` ``[n]`` and the torque ``[n]`` N·m."""
        new = dahl_advance(st, q, qd, self.level, self.rho, self.reversal_velocity)
        return new, dahl_value(new, q, self.rho)

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        rt = travel or motion_reversal_travel(s, self.reversal_velocity)
        return dahl_batch(rt, np.broadcast_to(self.level, s.q.shape), self.rho)
