"""The causal (online) counterpart of :mod:`proprio.conditioning`: the design of a state-variable filter stage that
sees only the past (:func:`causal_conditioning`, :class:`CausalConditioning`, over a whole log
:meth:`CausalConditioning.condition`); its Drake System is :class:`proprio.systems.causal_conditioning.CausalConditioner`,
its per-sample step in the streaming estimator :class:`proprio.discrete_lti.DiscreteLti`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.signal

from proprio.discrete_lti import DiscreteLti

__all__ = ["CausalConditioning", "causal_conditioning"]


@dataclass(frozen=True)
class CausalConditioning:
    """A causal conditioning stage for online use: per joint a 2nd-order Butterworth low-pass of ``q`` (or of the
    robot's own ``q̇``) as a *state-variable filter*, whose states are the filtered signal and its derivative, so that
    q̂, q̂̇, q̂̈ are ``H(s)·q``, ``s·H(s)·q``, ``s²·H(s)·q`` with one ``H(s) = ω_c² / (s² + √2 ω_c s + ω_c²)``; τ_J
    gets the same ``H`` (``tau_filter``), so that a prediction from the conditioned motion and the measurement it is
    compared with carry the same lag. Discretised by the bilinear transform pre-warped at the cutoff (the −3 dB point
    is exact) into one discrete-time LTI system ``x⁺ = A x + B u``, ``y = C x + D u`` at ``rate_hz``.

    Ports, stacked: ``u = [q (n) rad; τ_J (n) N·m]`` — or ``[q; q̇ (n) rad/s; τ_J]`` with ``velocity == "measured"``
    — and ``y = [q̂; q̂̇; q̂̈; τ̂_J]`` (rad, rad/s, rad/s², N·m). With a measured q̇, q̂̇ and q̂̈ come from the same filter on
    q̇ (``H·q̇``, ``s·H·q̇``), q̂ from ``H·q``.

    How it differs from :func:`proprio.conditioning.condition` (offline, zero phase): it sees only the past, so
    every channel lags — a group delay of ``√2 / ω_c`` at low frequency (45 ms at 5 Hz, 11 ms at 20 Hz) — and its
    magnitude is ``|H|`` once, not ``|H|²``. The torque model is evaluated on lagged (q̂, q̂̇, q̂̈) and compared
    with the equally lagged τ̂_J:
    the linear parts of the dynamics then match exactly; the non-linear ones (gravity, Coriolis, friction) see a
    signal delayed by ≈ √2/ω_c, so choose the cutoff as high as the q̈ noise allows (the ``auto`` cutoff of a
    previous log of the same robot, ``condition(rec).cutoff_hz``, is the offline optimum for a zero-phase filter
    of twice the order — a safe, if conservative, choice). The start-up transient is avoided by starting in the
    steady state of the first sample (:meth:`initial_state`).
    """
    rate_hz: float
    cutoff_hz: tuple[float, ...]
    velocity: str
    tau_filter: bool
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @property
    def n(self) -> int:
        return len(self.cutoff_hz)

    @property
    def time_step(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def group_delay_s(self) -> np.ndarray:
        """Low-frequency group delay ``√2 / ω_c`` [s] per joint (the lag of every output channel)."""
        return np.sqrt(2.0) / (2 * np.pi * np.asarray(self.cutoff_hz))

    @property
    def input_size(self) -> int:
        return (3 if self.velocity == "measured" else 2) * self.n

    def initial_state(self, u0: np.ndarray) -> np.ndarray:
        """The steady state ``x = (I − A)⁻¹ B u0`` for a constant input ``u0`` (the first sample): the outputs
        start at q̂ = q0, q̂̇ = q̂̈ = 0 (or the measured q̇0), τ̂ = τ0, with no start-up transient."""
        return np.linalg.solve(np.eye(self.A.shape[0]) - self.A, self.B @ np.asarray(u0, dtype=float))

    def condition(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """The stage over a whole log, vectorised form of the Diagram's conditioner: the stacked raw inputs ``u
        [N, input_size]`` (``[q; τ_J]`` or ``[q; q̇; τ_J]`` per sample) from the steady state of the first sample →
        ``q``, ``qd``, ``qdd``, ``tau`` ``[N,n]`` (rad, rad/s, rad/s², N·m) and ``time_step`` [s]: the same matrices
        stepped by the same kernel as the streaming estimator (:class:`~proprio.discrete_lti.DiscreteLti`)."""
        u = np.asarray(u, dtype=float)
        if u.ndim != 2 or u.shape[1] != self.input_size or u.shape[0] == 0:
            raise ValueError(f"CausalConditioning.condition: u must be [N, {self.input_size}] with N >= 1, got "
                             f"shape {list(u.shape)}")
        lti = DiscreteLti(self.A, self.B, self.C, self.D)
        lti.x[:] = self.initial_state(u[0])
        y, n = lti.response(u), self.n
        return {"q": y[:, :n], "qd": y[:, n:2 * n], "qdd": y[:, 2 * n:3 * n], "tau": y[:, 3 * n:],
                "time_step": self.time_step}


def causal_conditioning(rate_hz: float, cutoff_hz: float | Sequence[float], n: int, velocity: str = "q",
                        tau_filter: bool = True) -> CausalConditioning:
    """Design the causal conditioning stage (:class:`CausalConditioning`) for ``n`` joints sampled at ``rate_hz``
    with one cutoff [Hz] or one per joint (from a config, or ``condition(previous_log).cutoff_hz``); ``velocity``
    ``"q"`` differentiates q, ``"measured"`` filters the robot's own q̇ instead."""
    cut = np.broadcast_to(np.asarray(cutoff_hz, dtype=float), (n,)).copy()
    if velocity not in ("q", "measured"):
        raise ValueError(f"causal_conditioning: velocity must be 'q' or 'measured', got {velocity!r}")
    if not rate_hz > 0 or np.any(cut <= 0) or np.any(cut >= 0.5 * rate_hz):
        raise ValueError(f"causal_conditioning: cutoffs {cut} Hz must lie in (0, {0.5 * rate_hz:.6g}) Hz, the Nyquist "
                         f"frequency of {rate_hz:.6g} Hz")
    h = 1.0 / rate_hz
    blocks = []                                            # per joint and channel: (A, B, C [3 rows], D)
    for c in cut:
        w = 2.0 / h * np.tan(np.pi * c * h)               # pre-warped so that the bilinear map keeps |H| = 1/√2 at c
        a = np.array([[0.0, 1.0], [-w * w, -np.sqrt(2.0) * w]])
        b = np.array([[0.0], [w * w]])
        cc = np.array([[1.0, 0.0], [0.0, 1.0], [-w * w, -np.sqrt(2.0) * w]])      # x1, x2 = ẋ1, ẋ2
        dd = np.array([[0.0], [0.0], [w * w]])
        blocks.append(scipy.signal.cont2discrete((a, b, cc, dd), h, method="bilinear")[:4])
    channels = ["q", "qd", "tau"] if velocity == "measured" else ["q", "tau"]
    m = len(channels)
    A = np.zeros((2 * m * n, 2 * m * n))
    B = np.zeros((2 * m * n, m * n))
    C = np.zeros((4 * n, 2 * m * n))
    D = np.zeros((4 * n, m * n))
    for k, ch in enumerate(channels):
        for j, (ad, bd, cd, ddd) in enumerate(blocks):
            xs = slice(2 * (k * n + j), 2 * (k * n + j) + 2)
            ui = k * n + j
            A[xs, xs], B[xs, ui] = ad, bd[:, 0]
            if ch == "q":                                  # q̂ (and q̂̇, q̂̈ when differentiating q)
                rows = [(0, j, 0)] + ([] if velocity == "measured" else [(1, n + j, 1), (2, 2 * n + j, 2)])
            elif ch == "qd":                               # q̂̇ = H q̇, q̂̈ = s H q̇
                rows = [(0, n + j, 0), (1, 2 * n + j, 1)]
            else:
                rows = [(0, 3 * n + j, 0)]
            for src, dst, _ in rows:
                C[dst, xs], D[dst, ui] = cd[src], ddd[src, 0]
            if ch == "tau" and not tau_filter:             # pass τ_J through unfiltered
                C[3 * n + j, xs], D[3 * n + j, ui] = 0.0, 1.0
    return CausalConditioning(float(rate_hz), tuple(float(x) for x in cut), velocity, bool(tau_filter), A, B, C, D)
