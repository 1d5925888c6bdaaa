"""The joint-effect base class: per-joint parameters with bounds, simulate (:meth:`JointEffect.torque`) and fit
(:meth:`JointEffect.vector`, :meth:`JointEffect.with_vector`, :meth:`JointEffect.regressor`); helpers shared by the
effects."""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from proprio.reversals import ReversalTravel, reversal_travel
from proprio.signals import MotionSignals

__all__ = ["EffectConfigError", "JointEffect", "diagonal_regressor", "motion_reversal_travel",
           "reversal_key", "INF", "TINY"]

INF = math.inf
TINY = 1e-9


class EffectConfigError(ValueError):
    """A joint-effect configuration is invalid; the message names the effect and the field."""


def motion_reversal_travel(s: MotionSignals, reversal_velocity: float | np.ndarray) -> ReversalTravel:
    """:func:`proprio.reversals.reversal_travel` of ``s``'s ``(q, q̇)`` with the deadband ``reversal_velocity``
    [rad/s], computed once per signals and deadband (memoised in ``s.derived``: a fit evaluates the reversal effects
    many times on the same motion)."""
    eps = np.asarray(reversal_velocity, dtype=float)
    key = reversal_key(eps)
    if key not in s.derived:
        s.derived[key] = reversal_travel(s.q, s.qd, eps if eps.ndim else float(eps))
    return s.derived[key]


def reversal_key(reversal_velocity: float | np.ndarray) -> tuple:
    """The key of the reversal travel with deadband ``reversal_velocity`` in ``MotionSignals.derived``."""
    eps = np.asarray(reversal_velocity, dtype=float)
    return ("reversal_travel", eps.shape, eps.tobytes())


class JointEffect(ABC):
    """One joint effect with per-joint parameter arrays (shape ``[n]``).

    Subclasses declare ``parameters`` (fitted: name → (default, lower, upper); these form :meth:`vector`) and
    ``settings`` (fixed per-joint hyper-parameters: name → (default, lower, upper)). A lower bound of ``0.0`` is
    inclusive; where a value must be strictly positive the lower bound is a tiny positive number. ``prior_std``
    (parameter name → σ in its units) is a zero-mean Gaussian prior a linear fit adds (:meth:`prior_precision`): the
    scale physics gives a parameter, which settles a direction the data cannot (a torque-sensor gain against the
    rigid body's overall mass scale, whose torques are the same); with enough data it changes nothing.
    """
    name: ClassVar[str]
    place: ClassVar[str]                       # "motor" | "link" | "sensor"
    linear: ClassVar[bool]
    time_varying: ClassVar[bool] = False       # the torque depends on the session clock MotionSignals.t
    parameters: ClassVar[dict[str, tuple[float, float, float]]] = {}
    settings: ClassVar[dict[str, tuple[float, float, float]]] = {}
    prior_std: ClassVar[dict[str, float]] = {}

    def __init__(self, n: int, **params: Any) -> None:
        self.n = int(n)
        spec = {**self.parameters, **self.settings}
        unknown = sorted(set(params) - set(spec))
        if unknown:
            raise EffectConfigError(f"{self.name}: unknown field(s) {unknown}; valid fields: {sorted(spec)}")
        self._values: dict[str, np.ndarray] = {}
        for key, (default, lower, upper) in spec.items():
            arr = self._per_joint(key, params.get(key, default))
            if np.any(arr < lower) or np.any(arr > upper):
                bad = arr[(arr < lower) | (arr > upper)][0]
                raise EffectConfigError(f"{self.name}.{key} = {bad:g} is outside [{lower:g}, {upper:g}]")
            self._values[key] = arr

    def _per_joint(self, key: str, value: Any) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise EffectConfigError(f"{self.name}.{key} must be a number or a list of {self.n} numbers") from exc
        if arr.ndim == 0:
            arr = np.full(self.n, float(arr))
        if arr.shape != (self.n,):
            raise EffectConfigError(f"{self.name}.{key} must be a number or a list of {self.n} numbers, got shape "
                                    f"{list(arr.shape)}")
        if not np.all(np.isfinite(arr)):
            raise EffectConfigError(f"{self.name}.{key} must be finite")
        return arr

    def __getattr__(self, key: str) -> np.ndarray:
        values = self.__dict__.get("_values")
        if values is not None and key in values:
            return values[key]
        raise AttributeError(key)

    def __repr__(self) -> str:
        body = ", ".join(f"{k}={np.array2string(v, precision=4)}" for k, v in self._values.items())
        return f"{type(self).__name__}({body})"

    @classmethod
    def from_config(cls, block: dict | None, n: int) -> "JointEffect":
        """Build from a YAML block; scalars broadcast to ``n`` joints, keys ending ``_deg`` are converted to rad."""
        if block is not None and not isinstance(block, dict):
            raise EffectConfigError(f"{cls.name}: the YAML block must be a mapping of fields, got {block!r}")
        params = {}
        for key, value in (block or {}).items():
            if key.endswith("_deg"):
                key, value = key[:-4], np.radians(np.asarray(value, dtype=float))
            params[key] = value
        return cls(n, **params)

    def params(self) -> dict[str, np.ndarray]:
        """All per-joint parameters and settings (copies)."""
        return {k: v.copy() for k, v in self._values.items()}

    def vector(self) -> np.ndarray:
        """The fitted parameters, concatenated in ``parameters`` order (each ``[n]``)."""
        if not self.parameters:
            return np.zeros(0)
        return np.concatenate([self._values[k] for k in self.parameters])

    def with_vector(self, theta: np.ndarray) -> "JointEffect":
        """A copy with the fitted parameters replaced by ``theta`` (settings unchanged)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (len(self.parameters) * self.n,):
            raise ValueError(f"{self.name}: theta must have {len(self.parameters) * self.n} entries, got {theta.shape}")
        new = {k: theta[i * self.n:(i + 1) * self.n] for i, k in enumerate(self.parameters)}
        settings = {k: self._values[k] for k in self.settings}
        return type(self)(self.n, **new, **settings)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of :meth:`vector` (for ``scipy.optimize.least_squares``)."""
        lo = np.concatenate([np.full(self.n, spec[1]) for spec in self.parameters.values()] or [np.zeros(0)])
        hi = np.concatenate([np.full(self.n, spec[2]) for spec in self.parameters.values()] or [np.zeros(0)])
        return lo, hi

    def prior_precision(self) -> np.ndarray:
        """``1/σ²`` of the ``prior_std`` prior per entry of :meth:`vector` (0: no prior), in 1/(parameter unit)²."""
        return np.concatenate([np.full(self.n, self.prior_std[k] ** -2.0 if k in self.prior_std else 0.0)
                               for k in self.parameters] or [np.zeros(0)])

    @abstractmethod
    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        """Additive contribution to the measured τ_J, ``[N, n]`` N·m (``rng``: seeded generator for random
        effects)."""

    def regressor(self, s: MotionSignals) -> np.ndarray:
        """``[N, n, len(vector())]`` with ``torque == einsum("tnp,p->tn", regressor, vector())`` (linear effects)."""
        raise NotImplementedError(f"{self.name} is nonlinear in its parameters; fit it with least squares on "
                                  "vector()/with_vector()/bounds()")

    def _check_n(self, s: MotionSignals) -> None:
        if s.n != self.n:
            raise ValueError(f"{self.name}: configured for {self.n} joints, signals have {s.n}")

    def _load_scale(self, s: MotionSignals, base: np.ndarray, load_gain: np.ndarray) -> np.ndarray:
        """``base + load_gain·|τ|`` per sample (``[N,n]``); needs ``s.tau`` when any load gain is non-zero."""
        if not np.any(load_gain):
            return np.broadcast_to(base, s.q.shape)
        if s.tau is None:
            raise ValueError(f"{self.name}: load_gain is set, so MotionSignals.tau (link-side torque) is required")
        return base + load_gain * np.abs(s.tau)


def diagonal_regressor(columns: list[np.ndarray]) -> np.ndarray:
    """Stack per-joint columns ``[N,n]`` (one per parameter block) into ``[N, n, len(columns)·n]``."""
    n_s, n = columns[0].shape
    reg = np.zeros((n_s, n, len(columns) * n))
    jj = np.arange(n)
    for b, col in enumerate(columns):
        reg[:, jj, b * n + jj] = col
    return reg
