"""A torque that depends on the configuration alone (a gravity-compensation spring ``k (q − q₀)``, a cable's
``∝ sin q``): the *position is not history* test of the reversal candidates.

Hysteresis, lost motion and pre-sliding friction are functions of the motion's history — the travel since the last
reversal. Along a trajectory the travel is also correlated with where the arm is, so a torque that depends on the
configuration only can pose as a reversal effect. :class:`ConfigurationCandidate` is a linear nuisance with, per
joint ``j``, the columns ``1, q_j, sin q_j, cos q_j`` of the joint's own angle (a spring ``k (q_j − q_0)``, a cable's
``sin q_j``); fitted on the training data, it predicts the held-out data like any candidate. Few columns on purpose: a
richer basis (harmonics, the neighbours' angles) extrapolates from one motion to another with errors that swamp the
comparison. For the same reason it acts only on the joints where these columns explain a significant part of the
*training* residual beyond a constant (``joints``; chosen by the selection): fitted on every joint it would soak up
on the others whatever its columns and a competing candidate's share (a gravity-loaded joint's torque is nearly a
function of its angle), and extrapolate that to the held-out data as error.

A candidate of :data:`POSITION_MIMICS` is set aside when this nuisance explains as much and the candidate adds
nothing significant *beyond* it (:func:`proprio.diagnosis.selection.forward.attribute`, "Position is not
history"); the nuisance is never named itself — what it explains is left for the hints, which name the q it follows.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from proprio.diagnosis.candidates.base import Candidate, _kept_signals
from proprio.diagnosis.data import GapData

__all__ = ["ConfigurationCandidate", "REVERSAL_CANDIDATES", "POSITION_MIMICS", "own_angle_columns"]

REVERSAL_CANDIDATES = ("hysteresis", "lost_motion", "presliding")
"""The candidates whose torque is a function of the motion's history (the travel since the last reversal)."""

POSITION_MIMICS = REVERSAL_CANDIDATES + ("sensor_gain",)
"""The candidates a configuration-only torque can pose as: the reversal ones (the travel since the last reversal
follows where the arm is along a trajectory) and the torque-sensor gain error ``g τ`` (the measured torque follows
the configuration through gravity, and through ``q̈ ≈ −ω² q`` on a periodic motion). Not the offsets, the rigid body
or the payload: a constant and the gravity torque *are* configuration torques, named by the library."""

_COLUMNS = ("1", "q", "sin q", "cos q")


class ConfigurationCandidate(Candidate):
    """The configuration-only nuisance of the module docstring (``len(_COLUMNS)`` columns per joint) on the joints
    ``joints`` (0-based; default: all ``n``)."""
    name = "configuration"
    place = "link"

    def __init__(self, n: int, joints: Sequence[int] | None = None):
        self.n = n
        self.joints = np.arange(n) if joints is None else np.asarray(sorted(joints), dtype=int)
        self._per = len(_COLUMNS)

    def param_names(self) -> list[str]:
        return [f"{c}[{j + 1}]" for j in self.joints for c in _COLUMNS]

    def design(self, data: GapData) -> np.ndarray:
        cols = own_angle_columns(data)                                             # [M, n, per]
        d = np.zeros(cols.shape[:2] + (len(self.joints) * self._per,))
        for k, j in enumerate(self.joints):
            d[:, j, k * self._per:(k + 1) * self._per] = cols[:, j]
        return d

    @property
    def design_key(self) -> tuple:
        return self.name, tuple(self.joints)                                       # one design per joint set

    def joint_of_param(self, n: int) -> np.ndarray:
        return np.repeat(self.joints, self._per)


def own_angle_columns(data: GapData) -> np.ndarray:
    """``[M, n, len(_COLUMNS)]``: the columns ``1, q_j, sin q_j, cos q_j`` of each joint's own angle [rad] at the
    data's kept samples."""
    q = np.concatenate([s.q for s in _kept_signals(data)])
    return np.stack([np.ones_like(q), q, np.sin(q), np.cos(q)], axis=2)
