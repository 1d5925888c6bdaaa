"""The link-side motion that joint effects are functions of (:class:`MotionSignals`).

Where its ``q̇``, ``q̈`` come from is not this module's business: measured data get them from the one conditioning
path (:func:`proprio.conditioning.condition`, ``ConditionedSignals.motion()``), the twin from its exact simulated
motion.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["MotionSignals"]


@dataclass(frozen=True)
class MotionSignals:
    """Link-side motion that effects are functions of (SI units, shapes ``[N]`` / ``[N, n]``).

    ``tau`` (optional) is the link-side torque the sensor sees before the effect is applied: the gain error scales
    it, and load-dependent amplitudes (``load_gain``) grow with ``|tau|``. The twin passes its true τ_J; a fit on
    measured data may pass the measured or modelled τ.

    ``derived`` memoises quantities of the motion that do not depend on an effect's parameters (the reversal travel
    of :func:`proprio.effects.base.motion_reversal_travel`), so that a fit evaluating an effect many times on the same
    signals computes them once; the arrays are not to be changed in place.
    """
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray | None = None
    derived: dict[Any, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.q.ndim != 2 or self.qd.shape != self.q.shape or self.qdd.shape != self.q.shape:
            raise ValueError(f"MotionSignals: q, qd, qdd must all be [N, n], got {self.q.shape}, {self.qd.shape}, "
                             f"{self.qdd.shape}")
        if self.t.shape != (self.q.shape[0],):
            raise ValueError(f"MotionSignals: t must be [N] = [{self.q.shape[0]}], got {self.t.shape}")
        if self.tau is not None and self.tau.shape != self.q.shape:
            raise ValueError(f"MotionSignals: tau must be {self.q.shape}, got {self.tau.shape}")

    @property
    def n(self) -> int:
        return int(self.q.shape[1])

    def with_tau(self, tau: np.ndarray | None) -> "MotionSignals":
        """The same motion with the link-side torque ``tau`` (its memoised motion quantities shared)."""
        out = MotionSignals(self.t, self.q, self.qd, self.qdd, tau)
        object.__setattr__(out, "derived", self.derived)
        return out
