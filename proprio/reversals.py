"""Direction reversals of joint motion: the Schmitt-trigger direction of q̇ and the reversal travel r (signed joint
travel since the last reversal, the state of hysteresis and lost motion and the thesis' feature r, §4.2).

The law is a recursion over samples (the held direction, the running extrema of the segment), written once as numba
kernels (``cache=True``: compiled on the first call of a fresh install, a few seconds, then loaded from the cache).
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["ReversalCarry", "ReversalTravel", "motion_direction", "reversal_travel"]


@dataclass(frozen=True)
class ReversalCarry:
    """The reversal state carried from one piece of a motion into the next (each ``[n]``): the held direction ``d``
    ∈ {−1, 0, +1} of the last sample, the running extrema ``hi``/``lo`` [rad] of q in the current segment, its
    ``anchor`` [rad] and the number of reversals so far ``segments`` (the current segment's index). A motion cut
    into pieces and segmented piece by piece with the carry (:func:`reversal_travel`) gives the whole motion's
    segmentation (tests)."""
    d: np.ndarray
    hi: np.ndarray
    lo: np.ndarray
    anchor: np.ndarray
    segments: np.ndarray

    @classmethod
    def start(cls, q0: np.ndarray) -> "ReversalCarry":
        """The state before a motion that starts at ``q0 [n]`` [rad]: no direction yet, segment 0 anchored at q0."""
        q0 = np.asarray(q0, dtype=float)
        return cls(np.zeros_like(q0), q0.copy(), q0.copy(), q0.copy(), np.zeros_like(q0))

    def vector(self) -> np.ndarray:
        """``[5n]``: the fields in declaration order (numbers a Drake discrete state can hold)."""
        return np.concatenate([self.d, self.hi, self.lo, self.anchor, self.segments])

    @classmethod
    def from_vector(cls, v: np.ndarray) -> "ReversalCarry":
        return cls(*np.split(np.asarray(v, dtype=float), 5))


@dataclass(frozen=True)
class ReversalTravel:
    """Per-joint reversal segmentation of a motion.

    ``r [N,n]`` rad: signed travel since the last direction reversal (``q − anchor``); ``direction [N,n]`` ∈ {−1, 0,
    +1}: the current direction (0 until the joint first moves); ``segment [N,n]``: segment
    index per joint (0 = from the start to the first reversal). Per joint ``j``: ``starts[j]`` first sample of each
    segment, ``anchors[j]`` the position each segment's travel is measured from (q[0] for segment 0, else the
    extremum reached in the previous segment), ``seg_direction[j]``.
    """
    r: np.ndarray
    direction: np.ndarray
    segment: np.ndarray
    starts: tuple[np.ndarray, ...]
    anchors: tuple[np.ndarray, ...]
    seg_direction: tuple[np.ndarray, ...]
    end: ReversalCarry | None = None


@numba.njit(cache=True)
def _held(v: float, eps: float, d: float) -> float:
    """The Schmitt trigger: the direction after a sample of velocity ``v`` with deadband ``eps``, ``d`` held before."""
    return 1.0 if v > eps else (-1.0 if v < -eps else d)


@numba.njit(cache=True)
def _direction_kernel(qd, eps, d0):                                       # pragma: no cover (compiled)
    n_s, n = qd.shape
    out = np.empty((n_s, n))
    for j in range(n):
        d = d0[j]
        for i in range(n_s):
            d = _held(qd[i, j], eps[j], d)
            out[i, j] = d
    return out


@numba.njit(cache=True)
def _travel_kernel(q, qd, eps, d0, hi0, lo0, anc0, seg0, offsets, starts, anchors, seg_dirs):  # pragma: no cover
    """Fill r, direction, segment [N, n] and each joint's segments (at ``offsets[j]`` of the flat ``starts``,
    ``anchors``, ``seg_dirs``); returns them with the end state ``[5, n]``."""
    n_s, n = q.shape
    r = np.empty((n_s, n))
    direction = np.empty((n_s, n))
    segment = np.empty((n_s, n), dtype=np.int64)
    end = np.empty((5, n))
    for j in range(n):
        d, hi, lo, anc, k, o = d0[j], hi0[j], lo0[j], anc0[j], 0, offsets[j]
        starts[o] = 0
        anchors[o] = anc
        for i in range(n_s):
            x = q[i, j]
            nd = _held(qd[i, j], eps[j], d)
            if nd != d and d != 0.0:          # a reversal: the ending segment's extremum anchors the new one
                seg_dirs[o + k] = d
                anc = hi if d > 0 else lo
                k += 1
                starts[o + k] = i
                anchors[o + k] = anc
                hi = x
                lo = x
            else:
                hi = max(hi, x)
                lo = min(lo, x)
            d = nd
            r[i, j] = x - anc
            direction[i, j] = d
            segment[i, j] = seg0[j] + k
        seg_dirs[o + k] = d
        end[0, j], end[1, j], end[2, j], end[3, j], end[4, j] = d, hi, lo, anc, seg0[j] + k
    return r, direction, segment, end


@numba.njit(cache=True)
def _reversal_count(qd, eps, d0):                                        # pragma: no cover (compiled)
    n_s, n = qd.shape
    count = np.zeros(n, dtype=np.int64)
    for j in range(n):
        d = d0[j]
        for i in range(n_s):
            nd = _held(qd[i, j], eps[j], d)
            if nd != d and d != 0.0:
                count[j] += 1
            d = nd
    return count


def motion_direction(qd: np.ndarray, reversal_velocity: float | np.ndarray,
                     initial: np.ndarray | None = None) -> np.ndarray:
    """Direction of motion per joint, ``[N,n]`` ∈ {−1, 0, +1}: +1 while ``q̇ > reversal_velocity``, −1 while
    ``q̇ < −reversal_velocity``, and the last such value inside the band (a Schmitt trigger, so noise around a
    standstill does not flip it); ``initial [n]`` (default 0) until the joint first leaves the band — the direction
    held before these samples. ``reversal_velocity`` [rad/s], scalar or per joint."""
    qd = np.ascontiguousarray(np.atleast_2d(np.asarray(qd, dtype=float)))
    n = qd.shape[1]
    eps = np.ascontiguousarray(np.broadcast_to(np.asarray(reversal_velocity, dtype=float), (n,)))
    d0 = np.zeros(n) if initial is None else np.asarray(initial, dtype=float)
    return _direction_kernel(qd, eps, d0)


def reversal_travel(q: np.ndarray, qd: np.ndarray, reversal_velocity: float | np.ndarray = 2e-3,
                    carry: ReversalCarry | None = None) -> ReversalTravel:
    """Segment ``q [N,n]`` at direction reversals and return the signed travel since the last one.

    A joint's direction switches only when ``|q̇|`` exceeds ``reversal_velocity`` [rad/s] with the opposite sign
    (a deadband: noise around standstill keeps the previous direction). The travel after a reversal is measured
    from the extremum of q in the segment that ended, so a late detection does not shift r.

    ``carry``: the state at the end of the motion's previous piece (:attr:`ReversalTravel.end` of it); without it
    the motion starts here (:meth:`ReversalCarry.start`). The first segment is then the one carried in (it may end
    at the first sample: ``starts[j]`` begins ``[0, 0, ...]``), ``segment`` and ``anchors`` continue the carried ones.
    """
    q = np.ascontiguousarray(q, dtype=float)
    qd = np.ascontiguousarray(qd, dtype=float)
    n_s, n = q.shape
    c = ReversalCarry.start(q[0]) if carry is None else carry
    eps = np.ascontiguousarray(np.broadcast_to(np.asarray(reversal_velocity, dtype=float), (n,)))
    seg0 = c.segments.astype(np.int64)
    sizes = _reversal_count(qd, eps, c.d) + 1
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    starts, anchors, seg_dirs = np.empty(offsets[-1], dtype=np.int64), np.empty(offsets[-1]), np.empty(offsets[-1])
    r, direction, segment, end = _travel_kernel(q, qd, eps, c.d, c.hi, c.lo, c.anchor, seg0, offsets, starts,
                                                anchors, seg_dirs)
    cut = [slice(offsets[j], offsets[j + 1]) for j in range(n)]
    return ReversalTravel(r, direction, segment, tuple(starts[k] for k in cut), tuple(anchors[k] for k in cut),
                          tuple(seg_dirs[k] for k in cut), ReversalCarry(*end.copy()))
