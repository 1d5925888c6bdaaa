"""Input features of the hybrid models (§4.2): the rotational-displacement encoding r and vec(τ_RBD, q, q̇, q̈, r).

Rotational displacement since the last direction reversal (§4.2, "Rotational Displacement Encoding")
--------------------------------------------------------------------------------------------------------
``r_j(t) = clip(q_j(t) − a_j, ±r_max)`` with ``a_j`` the joint angle at the last confirmed direction reversal of joint
j and ``r_max = 10°`` (hysteresis saturates there, Fig. 2.5).

Noise robustness — a reversal needs travel, not a sign flip. Encoder noise flips the sign of Δq at every sample of
a slow or resting joint, so a reversal is *confirmed* only once the joint has travelled back more than a deadband
``h`` (config ``reversal_deadband_deg``, default 0.05°, far below the ≈1° lost-motion window and far above encoder
noise) from its running extremum in the current direction (a peak detector with hysteresis). The reversal point
``a_j`` is that extremum (the true turning point), not the sample where it was confirmed. The rule is causal, so
the streaming encoder (:class:`ReversalEncoder`, used online by the residual System) and the offline one
(:func:`rotational_displacement`) give bit-identical results; the price is a detection delay of ``h`` of travel,
during which r still counts from the previous reversal. The first sample counts as a reversal point with direction
"up" (a joint that starts moving down confirms a reversal at once, at its first extremum).

Per joint the state is ``(d, e, a)``: direction ±1, running extremum in direction d, reversal point; per sample::

    e ← max(d·e, d·q)·d            (running extremum)
    if d·e − d·q > h:  a ← e, d ← −d, e ← q   (reversal confirmed)
    r = clip(q − a, −r_max, r_max)

The per-sample step is one compiled kernel (:func:`reversal_step`, numba): the streaming encoder calls it once per
sample, the offline one runs it over the samples in a compiled loop, so both are the same law, bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numba
import numpy as np

from proprio import friction_law

__all__ = ["R_MAX_DEG", "DEFAULT_DEADBAND_DEG", "TauRbdProvider", "rotational_displacement", "ReversalEncoder",
           "feature_matrix", "feature_names", "feature_columns", "rbd_provider"]

R_MAX_DEG = 10.0
DEFAULT_DEADBAND_DEG = 0.05

TauRbdProvider = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""``(q, qd, qdd) -> tau_rbd``, all ``[N, n]`` (rad, rad/s, rad/s², N·m): any rigid-body backbone."""


@numba.njit(cache=True)
def reversal_step(d, run, a, q, h, r_max, r_out):  # pragma: no cover (compiled)
    """The encoder's law for one sample, in place: the state ``d`` (direction ±1), ``run`` (signed running extremum
    d·e), ``a`` (reversal point) [n] advanced by ``q [n]`` rad with the deadband ``h`` [rad]; r [rad] (clipped to
    ±``r_max``) into ``r_out [n]``."""
    for j in range(q.shape[0]):
        s = d[j] * q[j]
        m = max(s, run[j])                                   # signed running extremum d·e
        if m - s > h:                                        # reversal confirmed
            a[j] = d[j] * m                                  # a ← e, the extremum
            d[j] = -d[j]                                     # d ← −d
            m = -s                                           # d·e ← (−d)·q
        run[j] = m
        r_out[j] = min(max(q[j] - a[j], -r_max), r_max)


@numba.njit(cache=True)
def _encode(q, h, r_max, out):  # pragma: no cover (compiled)
    """:func:`reversal_step` over the samples ``q [N,n]`` from the state at ``q[0]`` (direction up) → ``out [N,n]``."""
    n = q.shape[1]
    d, run, a = np.ones(n), q[0].copy(), q[0].copy()
    for k in range(q.shape[0]):
        reversal_step(d, run, a, q[k], h, r_max, out[k])


def rotational_displacement(q: np.ndarray, deadband_deg: float = DEFAULT_DEADBAND_DEG, r_max_deg: float = R_MAX_DEG
                            ) -> np.ndarray:
    """r ``[N, n]`` [rad]: each joint's travel since its last confirmed direction reversal, clipped to ±r_max.

    ``q [N, n]`` rad, sampled at the model's data rate; ``deadband_deg`` is the return travel that confirms a reversal
    (see the module docstring). Equals :class:`ReversalEncoder` fed one sample at a time, bit for bit.
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[0] == 0:
        raise ValueError(f"rotational_displacement: q must be [N, n] with N >= 1, got shape {list(q.shape)}")
    if deadband_deg < 0 or r_max_deg <= 0:
        raise ValueError("rotational_displacement: reversal_deadband_deg must be >= 0 and r_max_deg > 0")
    out = np.empty(q.shape)
    _encode(np.ascontiguousarray(q), float(np.radians(deadband_deg)), float(np.radians(r_max_deg)), out)
    return out


@dataclass
class ReversalEncoder:
    """Streaming form of :func:`rotational_displacement`: call :meth:`step` once per sample.

    The state is a flat vector ``[3n]`` so a Drake System can keep it as discrete state: per joint the direction
    ``d``, the signed running extremum ``m = d·e`` and the reversal point ``a`` (module docstring; keeping ``d·e``
    saves two products per sample and is exact, d = ±1). :meth:`initial_state`, :meth:`step_state` are the pure
    functions the System uses.
    """
    n: int
    deadband_deg: float = DEFAULT_DEADBAND_DEG
    r_max_deg: float = R_MAX_DEG

    def __post_init__(self) -> None:
        self.h = float(np.radians(self.deadband_deg))
        self.r_max = float(np.radians(self.r_max_deg))
        self.state: np.ndarray | None = None

    def initial_state(self, q0: np.ndarray) -> np.ndarray:
        """State ``[d(n), m(n), a(n)]`` before the first sample ``q0`` (direction up, reversal point q0)."""
        q0 = np.asarray(q0, dtype=float)
        return np.concatenate([np.ones(self.n), q0, q0])

    def step_state(self, state: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(r [n] rad, next state)`` for one sample ``q [n]``; ``state`` is not modified."""
        r, nxt = np.empty(self.n), np.empty(3 * self.n)
        self.step_into(state, q, nxt, r)
        return r, nxt

    def split_state(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Views ``(d, d·e, a)`` of a state vector (make them once per buffer, for :meth:`step_into`)."""
        n = self.n
        return state[:n], state[n:2 * n], state[2 * n:]

    def step_into(self, state: np.ndarray, q: np.ndarray, state_out: np.ndarray, r_out: np.ndarray,
                  parts_out: tuple[np.ndarray, ...] | None = None) -> None:
        """:meth:`step_state` into preallocated arrays (for the per-sample Systems): the next state into
        ``state_out [3n]`` (``parts_out``: its :meth:`split_state` views, if made already) and r [rad] into
        ``r_out [n]`` (neither may alias ``state`` or ``q``)."""
        state_out[:] = state
        d, run, a = self.split_state(state_out) if parts_out is None else parts_out
        reversal_step(d, run, a, q, self.h, self.r_max, r_out)

    def step(self, q: np.ndarray) -> np.ndarray:
        """r [n] rad for the next sample ``q [n]`` rad (the first call initialises the state)."""
        q = np.asarray(q, dtype=float)
        if self.state is None:
            self.state = self.initial_state(q)
        r, self.state = self.step_state(self.state, q)
        return r


def feature_names(n: int = 7) -> list[str]:
    """Names of the full feature vector vec(τ_RBD, q, q̇, q̈, r) (eq. 4.30), 5n entries."""
    return [f"{k}{j + 1}" for k in ("tau_rbd", "q", "qd", "qdd", "r") for j in range(n)]


def feature_columns(n: int, hybrid: bool, use_r: bool) -> np.ndarray:
    """Columns of the full 5n feature vector a model uses: τ_RBD only when hybrid, r only when use_r."""
    blocks = ([0] if hybrid else []) + [1, 2, 3] + ([4] if use_r else [])
    return np.concatenate([np.arange(b * n, (b + 1) * n) for b in blocks])


def feature_matrix(tau_rbd: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, r: np.ndarray) -> np.ndarray:
    """vec(τ_RBD, q, q̇, q̈, r) per sample: ``[N, 5n]`` (N·m, rad, rad/s, rad/s², rad) — 35 features for n = 7."""
    return np.concatenate([tau_rbd, q, qd, qdd, r], axis=-1)


def rbd_provider(desc) -> TauRbdProvider:
    """The default backbone τ_RBD = RNEA of ``desc`` (:func:`proprio.dynamics.inverse_dynamics`) plus its viscous and
    Coulomb friction ``f_v q̇ + f_c tanh(q̇/v_s)`` (the law and smoothing of :mod:`proprio.friction_law`) when the
    description has friction."""
    from proprio.dynamics import inverse_dynamics
    from proprio.kinematics import chain_geometry

    geo = chain_geometry(desc)
    fv = np.asarray(desc.friction_viscous) if desc.friction_viscous is not None else None
    fc = np.asarray(desc.friction_coulomb) if desc.friction_coulomb is not None else None

    def tau_rbd(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        tau = inverse_dynamics(desc, q, qd, qdd, geometry=geo)
        if fv is not None:
            tau = tau + friction_law.viscous_coulomb(qd, fv, fc)
        return tau

    return tau_rbd
