"""Direction reversals of joint motion: the Schmitt-trigger direction of q̇ and the reversal travel r (signed joint
travel since the last reversal, the state of hysteresis and lost motion and the thesis' feature r, §4.2)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ReversalTravel", "REVERSAL_FIELDS", "motion_direction", "reversal_start", "reversal_scan",
           "reversal_travel"]


@dataclass(frozen=True)
class ReversalTravel:
    """Per-joint reversal segmentation of a motion.

    ``r [N,n]`` rad: signed travel since the last direction reversal (``q − anchor``); ``direction [N,n]`` ∈ {−1, 0,
    +1}: the current direction (0 until the joint first moves); ``segment [N,n]``: segment
    index per joint (0 = from the start to the first reversal). Per joint ``j``: ``starts[j]`` first sample of each
    segment, ``anchors[j]`` the position each segment's travel is measured from (q[0] for segment 0, else the
    extremum reached in the previous segment), ``seg_direction[j]``; ``end``: the tracker state after the last sample
    (:func:`reversal_scan`).
    """
    r: np.ndarray
    direction: np.ndarray
    segment: np.ndarray
    starts: tuple[np.ndarray, ...]
    anchors: tuple[np.ndarray, ...]
    seg_direction: tuple[np.ndarray, ...]
    end: np.ndarray | None = None          # the tracker state after the last sample [5n] (REVERSAL_FIELDS)


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


REVERSAL_FIELDS = ("d", "reversed", "hi", "lo", "anchor")
"""The reversal tracker's state per joint, packed ``[5·n]`` in this order: direction d ∈ {−1, 0, +1}, has reversed
(0/1), running max / min of q in the current segment [rad], the current segment's anchor [rad]."""


def _raw_direction(qd: np.ndarray, reversal_velocity: np.ndarray) -> np.ndarray:
    return np.where(qd > reversal_velocity, 1.0, np.where(qd < -reversal_velocity, -1.0, 0.0))


def reversal_start(q0: np.ndarray, qd0: np.ndarray, reversal_velocity: float | np.ndarray = 2e-3) -> np.ndarray:
    """The tracker's state ``[5n]`` *before* a first sample ``(q0, q̇0)`` ``[n]``: that sample then starts segment 0
    at q0 without a reversal."""
    eps = np.broadcast_to(np.asarray(reversal_velocity, dtype=float), q0.shape)
    return np.concatenate([_raw_direction(qd0, eps), np.zeros_like(q0), q0, q0, q0])


def reversal_scan(x0: np.ndarray, q: np.ndarray, qd: np.ndarray, reversal_velocity: float | np.ndarray = 2e-3
                  ) -> ReversalTravel:
    """Segment ``q [N,n]`` at direction reversals, continuing from the tracker state ``x0`` ``[5n]``
    (:data:`REVERSAL_FIELDS`, e.g. :func:`reversal_start` or the ``end`` of the previous block): the one law of the
    reversal travel, for a whole motion or block by block (``reversal_scan(x0, a+b) == reversal_scan(end of a, b)``).

    A joint's direction switches only when ``|q̇|`` exceeds ``reversal_velocity`` [rad/s] with the opposite sign
    (a deadband: noise around standstill keeps the previous direction). The travel after a reversal is measured
    from the extremum of q in the segment that ended, so a late detection does not shift r. Segment 0 is the one
    ``x0`` was in (it may hold no sample of this block when the first sample reverses); ``starts[j][0] = 0``.
    """
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    n_s, n = q.shape
    eps = np.broadcast_to(np.asarray(reversal_velocity, dtype=float), (n,))
    d0, rev0, hi0, lo0, anc0 = (np.asarray(x0, dtype=float)[k * n:(k + 1) * n] for k in range(5))
    raw = np.vstack([d0, _raw_direction(qd, eps)])                       # row 0: the state's direction
    last = np.maximum.accumulate(np.where(raw != 0, np.arange(n_s + 1)[:, None], 0), axis=0)
    d_ext = np.take_along_axis(raw, last, axis=0)                        # forward-filled direction
    flip = (d_ext[1:] != d_ext[:-1]) & (d_ext[:-1] != 0)
    segment = np.cumsum(flip, axis=0)
    r = np.empty_like(q)
    starts, anchors, seg_dirs = [], [], []
    end = np.empty((5, n))
    for j in range(n):                                                    # loop over joints only
        st = np.flatnonzero(flip[:, j])
        st_ext = np.concatenate([[0], st + 1])                            # in [state; samples] indexing
        hi = np.maximum.reduceat(np.concatenate([[hi0[j]], q[:, j]]), st_ext)
        lo = np.minimum.reduceat(np.concatenate([[lo0[j]], q[:, j]]), st_ext)
        sd = d_ext[np.concatenate([st_ext[1:] - 1, [n_s]]), j]            # direction of each segment (its last)
        anc = np.concatenate([[anc0[j]], np.where(sd[:-1] > 0, hi[:-1], lo[:-1])])
        r[:, j] = q[:, j] - anc[segment[:, j]]
        starts.append(np.concatenate([[0], st]))
        anchors.append(anc)
        seg_dirs.append(sd)
        end[:, j] = (d_ext[-1, j], 1.0 if st.size else rev0[j], hi[-1], lo[-1], anc[-1])
    return ReversalTravel(r, d_ext[1:], segment, tuple(starts), tuple(anchors), tuple(seg_dirs), end.ravel())


def reversal_travel(q: np.ndarray, qd: np.ndarray, reversal_velocity: float | np.ndarray = 2e-3) -> ReversalTravel:
    """Segment ``q [N,n]`` at direction reversals and return the signed travel since the last one: the
    :func:`reversal_scan` of the whole motion from rest at its first sample."""
    q = np.asarray(q, dtype=float)
    return reversal_scan(reversal_start(q[0], np.asarray(qd, dtype=float)[0], reversal_velocity), q, qd,
                         reversal_velocity)
