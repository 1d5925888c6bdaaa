"""Direction reversals of joint motion: the Schmitt-trigger direction of q̇ and the reversal travel r (signed joint
travel since the last reversal, the state of hysteresis and lost motion and the thesis' feature r, §4.2)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ReversalTravel", "motion_direction", "reversal_travel"]


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


def motion_direction(qd: np.ndarray, reversal_velocity: float | np.ndarray) -> np.ndarray:
    """Direction of motion per joint, ``[N,n]`` ∈ {−1, 0, +1}: +1 while ``q̇ > reversal_velocity``, −1 while
    ``q̇ < −reversal_velocity``, and the last such value inside the band (a Schmitt trigger, so noise around a
    standstill does not flip it); 0 until the joint first leaves the band. ``reversal_velocity`` [rad/s], scalar or
    per joint."""
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    eps = np.broadcast_to(np.asarray(reversal_velocity, dtype=float), (qd.shape[1],))
    raw = np.where(qd > eps, 1.0, np.where(qd < -eps, -1.0, 0.0))
    last = np.maximum.accumulate(np.where(raw != 0, np.arange(qd.shape[0])[:, None], 0), axis=0)
    return np.take_along_axis(raw, last, axis=0)                          # forward-filled direction


def reversal_travel(q: np.ndarray, qd: np.ndarray, reversal_velocity: float | np.ndarray = 2e-3) -> ReversalTravel:
    """Segment ``q [N,n]`` at direction reversals and return the signed travel since the last one.

    A joint's direction switches only when ``|q̇|`` exceeds ``reversal_velocity`` [rad/s] with the opposite sign
    (a deadband: noise around standstill keeps the previous direction). The travel after a reversal is measured
    from the extremum of q in the segment that ended, so a late detection does not shift r.
    """
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    n_s, n = q.shape
    held = motion_direction(qd, reversal_velocity)
    r = np.empty_like(q)
    direction = np.empty((n_s, n))
    segment = np.empty((n_s, n), dtype=np.int64)
    starts, anchors, seg_dirs = [], [], []
    for j in range(n):                                                    # loop over joints only
        d = held[:, j]
        flip = np.zeros(n_s, dtype=bool)
        flip[1:] = (d[1:] != d[:-1]) & (d[:-1] != 0)
        seg = np.cumsum(flip)
        st = np.concatenate([[0], np.flatnonzero(flip)])
        ends = np.concatenate([st[1:] - 1, [n_s - 1]])
        sd = d[ends]                                                      # direction of each segment
        hi = np.maximum.reduceat(q[:, j], st)
        lo = np.minimum.reduceat(q[:, j], st)
        anc = np.concatenate([[q[0, j]], np.where(sd[:-1] > 0, hi[:-1], lo[:-1])])
        r[:, j] = q[:, j] - anc[seg]
        direction[:, j] = d
        segment[:, j] = seg
        starts.append(st)
        anchors.append(anc)
        seg_dirs.append(sd)
    return ReversalTravel(r, direction, segment, tuple(starts), tuple(anchors), tuple(seg_dirs))
