"""A discrete-time LTI stage stepped from Python — ``y = C x + D u``, then ``x ← A x + B u`` — as one compiled
kernel (:class:`DiscreteLti`; over samples, :meth:`DiscreteLti.response`, the same kernel in a compiled loop). It is
Drake's ``LinearSystem`` (discrete) semantics, for the streaming estimator and the batch path, which step the same
matrices as the Diagram's ``LinearSystem`` stages (the causal conditioner,
:func:`proprio.causal_conditioning.causal_conditioning`; the momentum observer, :func:`proprio.momentum.momentum_filter`)
without a Drake Context per sample."""
from __future__ import annotations

import numba
import numpy as np

__all__ = ["DiscreteLti"]


@numba.njit(cache=True)
def _lti_step(a, b, c, d, x, u, y):  # pragma: no cover (compiled)
    """``y = C x + D u``, then ``x ← A x + B u`` in place."""
    y[:] = np.dot(c, x) + np.dot(d, u)
    x[:] = np.dot(a, x) + np.dot(b, u)


@numba.njit(cache=True)
def _lti_response(a, b, c, d, x, u, y):  # pragma: no cover (compiled)
    """:func:`_lti_step` over the rows of ``u [N,m]`` → ``y [N,p]`` (x advanced in place)."""
    for k in range(u.shape[0]):
        _lti_step(a, b, c, d, x, u[k], y[k])


class DiscreteLti:
    """``x⁺ = A x + B u``, ``y = C x + D u`` with its state ``x`` (explicit, a numpy vector) — :meth:`step_into`
    per sample. Building it compiles (or loads from numba's cache) and runs the kernel once."""

    def __init__(self, a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray):
        self.a, self.b, self.c, self.d = (np.ascontiguousarray(m, dtype=float) for m in (a, b, c, d))
        self.x = np.zeros(self.a.shape[0])
        self.step_into(np.zeros(self.b.shape[1]), np.empty(self.c.shape[0]))
        self.x[:] = 0.0

    def step_into(self, u: np.ndarray, y_out: np.ndarray) -> None:
        """The output for input ``u`` into ``y_out`` (from the state before the sample), then the state update."""
        _lti_step(self.a, self.b, self.c, self.d, self.x, u, y_out)

    def response(self, u: np.ndarray) -> np.ndarray:
        """The outputs ``[N,p]`` for the inputs ``u [N,m]``, sample after sample from the present state (which is
        advanced): :meth:`step_into` over the samples in one compiled loop."""
        u = np.ascontiguousarray(u, dtype=float)
        y = np.empty((u.shape[0], self.c.shape[0]))
        _lti_response(self.a, self.b, self.c, self.d, self.x, u, y)
        return y
