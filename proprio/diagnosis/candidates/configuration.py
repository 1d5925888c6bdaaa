"""A torque that depends on the configuration alone (a gravity-compensation spring ``k (q − q₀)``, a cable's
``∝ sin q``): the *position is not history* test of the reversal candidates.

Hysteresis, lost motion and pre-sliding friction are functions of the motion's history — the travel since the last
reversal. Along a trajectory the travel is also correlated with where the arm is, so a torque that depends on the
configuration only can pose as a reversal effect. :class:`ConfigurationCandidate` is a linear nuisance with, per
joint ``j``, the columns ``1, q_j, sin q_j, cos q_j`` of the joint's own angle (a spring ``k (q_j − q_0)``, a cable's
``sin q_j``); fitted on the training data, it predicts the held-out data like any candidate. Few columns on purpose: a
richer basis (harmonics, the neighbours' angles) extrapolates from one motion to another with errors that swamp the
comparison. A reversal candidate is set aside when this nuisance explains as much and it adds nothing significant
*beyond* it (:func:`proprio.diagnosis.selection.forward.attribute`, "Position is not history"); it is never
named itself — what it explains is left for the hints, which name the q it follows.
"""
from __future__ import annotations

import numpy as np

from proprio.diagnosis.candidates.base import Candidate, _kept_signals
from proprio.diagnosis.data import GapData

__all__ = ["ConfigurationCandidate", "REVERSAL_CANDIDATES"]

REVERSAL_CANDIDATES = ("hysteresis", "lost_motion", "presliding")
"""The candidates whose torque is a function of the motion's history (the travel since the last reversal)."""

_COLUMNS = ("1", "q", "sin q", "cos q")


class ConfigurationCandidate(Candidate):
    """The configuration-only nuisance of the module docstring (``len(_COLUMNS)`` columns per joint)."""
    name = "configuration"
    place = "link"

    def __init__(self, n: int):
        self.n = n
        self._per = len(_COLUMNS)

    def param_names(self) -> list[str]:
        return [f"c{c}[{j + 1}]" for j in range(self.n) for c in range(self._per)]

    def design(self, data: GapData) -> np.ndarray:
        out = []
        for s in _kept_signals(data):
            q = s.q
            m, n = q.shape
            cols = np.stack([np.ones_like(q), q, np.sin(q), np.cos(q)], axis=2)      # [m, n, per]
            d = np.zeros((m, n, n * self._per))
            for j in range(n):
                d[:, j, j * self._per:(j + 1) * self._per] = cols[:, j]
            out.append(d)
        return np.concatenate(out)

    def joint_of_param(self, n: int) -> np.ndarray:
        return np.repeat(np.arange(n), self._per)
