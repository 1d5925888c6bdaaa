"""Direction reversals of joint motion: the Schmitt-trigger direction of q̇ and the reversal travel r (signed joint
travel since the last reversal, the state of hysteresis and lost motion and the thesis' feature r, §4.2)."""
from __future__ import annotations

from dataclasses import dataclass

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


def motion_direction(qd: np.ndarray, reversal_velocity: float | np.ndarray,
                     initial: np.ndarray | None = None) -> np.ndarray:
    """Direction of motion per joint, ``[N,n]`` ∈ {−1, 0, +1}: +1 while ``q̇ > reversal_velocity``, −1 while
    ``q̇ < −reversal_velocity``, and the last such value inside the band (a Schmitt trigger, so noise around a
    standstill does not flip it); ``initial [n]`` (default 0) until the joint first leaves the band — the direction
    held before these samples. ``reversal_velocity`` [rad/s], scalar or per joint."""
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    eps = np.broadcast_to(np.asarray(reversal_velocity, dtype=float), (qd.shape[1],))
    raw = np.where(qd > eps, 1.0, np.where(qd < -eps, -1.0, 0.0))
    raw = np.vstack([np.zeros(qd.shape[1]) if initial is None else np.asarray(initial, dtype=float), raw])
    last = np.maximum.accumulate(np.where(raw != 0, np.arange(raw.shape[0])[:, None], 0), axis=0)
    return np.take_along_axis(raw, last, axis=0)[1:]                      # forward-filled direction


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
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    n_s, n = q.shape
    c = ReversalCarry.start(q[0]) if carry is None else carry
    held = motion_direction(qd, reversal_velocity, c.d)
    r = np.empty_like(q)
    direction = np.empty((n_s, n))
    segment = np.empty((n_s, n), dtype=np.int64)
    starts, anchors, seg_dirs, end = [], [], [], []
    for j in range(n):                                                    # loop over joints only
        d = held[:, j]
        flip = np.empty(n_s, dtype=bool)
        flip[0] = (d[0] != c.d[j]) & (c.d[j] != 0)
        flip[1:] = (d[1:] != d[:-1]) & (d[:-1] != 0)
        seg = np.cumsum(flip)
        later = np.flatnonzero(flip)                                      # first sample of each later segment
        st = np.concatenate([[0], later])
        ends = np.concatenate([st[1:] - 1, [n_s - 1]])
        sd = np.where(ends >= 0, d[np.maximum(ends, 0)], c.d[j])           # direction of each segment
        head = q[:st[1] if later.size else n_s, j]                        # the carried segment's samples here
        hi = np.empty(st.size)
        lo = np.empty(st.size)
        hi[0] = max(c.hi[j], head.max()) if head.size else c.hi[j]
        lo[0] = min(c.lo[j], head.min()) if head.size else c.lo[j]
        if later.size:
            hi[1:] = np.maximum.reduceat(q[:, j], later)
            lo[1:] = np.minimum.reduceat(q[:, j], later)
        anc = np.concatenate([[c.anchor[j]], np.where(sd[:-1] > 0, hi[:-1], lo[:-1])])
        r[:, j] = q[:, j] - anc[seg]
        direction[:, j] = d
        segment[:, j] = int(c.segments[j]) + seg
        starts.append(st)
        anchors.append(anc)
        seg_dirs.append(sd)
        end.append((d[-1], hi[-1], lo[-1], anc[-1], float(segment[-1, j])))
    carry_out = ReversalCarry(*(np.array(v, dtype=float) for v in zip(*end)))
    return ReversalTravel(r, direction, segment, tuple(starts), tuple(anchors), tuple(seg_dirs), carry_out)
