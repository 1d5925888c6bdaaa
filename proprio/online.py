"""Streaming wrench estimation for the real robot: one sample in, one estimate out, from your own control loop.

For users who drive the estimator from their own loop (KUKA FRI at 1 kHz, a ROS 2 callback) rather than a Drake
``Simulator``::

    from proprio.online import OnlineEstimator

    est = OnlineEstimator.from_model("iiwa14_identified", rate_hz=1000.0, cutoff_hz=10.0)
    while running:                                   # every 1 ms
        t, q, tau_J = robot.read()                   # s, rad [7], N·m [7] (link-side torque sensors)
        w = est.step(t, q, tau_J)                    # or est.step(t, q, tau_J, qd) with velocity="measured"
        f = w.jacobian[:3]                           # N, on the robot at the flange origin, world frame

It runs the stages of :class:`proprio.diagrams.estimation.WrenchEstimator` with a causal conditioning stage
(:func:`proprio.conditioning.causal_conditioning`): it builds that Diagram and drives its Systems' own step
functions (the conditioner's and the momentum filter's LTI matrices, the rigid-body terms' ``calc``, the torque
model's ``step_into``, the wrench map's ``calc_jacobian``), so the numbers equal the Diagram's (tests: to 1e-9) without
the framework's per-step overhead. One difference in the work, not in the numbers: the rigid-body torque τ_rigid that
the Diagram's torque model gets from its own C++ ``InverseDynamics`` is M(q) q̈ + ID(q, q̇, 0) from the rigid-body
terms' plant quantities (one set of kinematics per sample, equal to rounding). Inputs are validated at the boundary
(shape, finiteness, time strictly increasing at the design rate); buffers are preallocated; one estimator serves
one robot from one thread.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from proprio.conditioning import CausalConditioning, causal_conditioning
from proprio.description import RobotDescription
from proprio.diagrams.estimation import (DEFAULT_GAIN, RigidBodyTorqueModel, TorqueModel, WrenchEstimator,
                                         load_torque_model)
from proprio.systems.observers import WrenchMapping

__all__ = ["WrenchEstimate", "OnlineEstimator", "OnlineInputError"]


class OnlineInputError(ValueError):
    """A sample handed to :meth:`OnlineEstimator.step` is malformed; the message names the field."""


class WrenchEstimate:
    """One estimate at time ``t`` [s] (the sample's own stamp), a read-only view of one vector (``vector``, the
    :class:`~proprio.diagrams.estimation.WrenchEstimator`'s ``estimate`` port; fields are sliced on access).

    ``jacobian``, ``momentum``: ``[fx, fy, fz, mx, my, mz]`` — the wrench the environment exerts ON the robot at the
    contact point (the flange origin by default), world frame, N and N·m (moment 0 in force-only mode), from the
    direct (Jacobian) and the momentum observer. ``tau_ext_jacobian``, ``tau_ext_momentum`` [n] N·m: the observers'
    external joint torques. ``manipulability`` √det(J W Jᵀ) and ``unreliable`` (σ_min below the threshold: the
    mapping is damped, trust the wrench less)."""
    __slots__ = ("t", "vector")

    def __init__(self, t: float, vector: np.ndarray):
        self.t, self.vector = t, vector

    @property
    def jacobian(self) -> np.ndarray:
        return self.vector[0:6]

    @property
    def momentum(self) -> np.ndarray:
        return self.vector[6:12]

    @property
    def manipulability(self) -> float:
        return float(self.vector[12])

    @property
    def unreliable(self) -> bool:
        return bool(self.vector[13] > 0.5)

    @property
    def tau_ext_jacobian(self) -> np.ndarray:
        n = (self.vector.shape[0] - 14) // 2
        return self.vector[14:14 + n]

    @property
    def tau_ext_momentum(self) -> np.ndarray:
        n = (self.vector.shape[0] - 14) // 2
        return self.vector[14 + n:]

    def __repr__(self) -> str:
        return (f"WrenchEstimate(t={self.t:.6g} s, jacobian={np.array2string(self.jacobian, precision=3)}, "
                f"momentum={np.array2string(self.momentum, precision=3)}, unreliable={self.unreliable})")


class OnlineEstimator:
    """The streaming estimator (module docstring). Build it with :meth:`from_model`; call :meth:`step` once per
    sample at ``rate_hz``; :meth:`reset` after a pause (the next sample starts it afresh)."""

    def __init__(self, estimator: WrenchEstimator, max_step_jitter: float = 0.5):
        if estimator.conditioner is None:
            raise ValueError("OnlineEstimator needs a WrenchEstimator with a causal conditioning stage")
        self.estimator = estimator
        self.description: RobotDescription = estimator.model.description
        self.n = n = self.description.n
        design = self.design = estimator.conditioner.design
        self.time_step = design.time_step
        self.max_step_jitter = float(max_step_jitter)
        self._velocity = design.velocity == "measured"
        # one product per filter and step: [y; x⁺] = [[C, D], [A, B]] [x; u] (the Systems' own matrices)
        ns = design.A.shape[0]
        self._cond = np.block([[design.C, design.D], [design.A, design.B]])
        mom = estimator.momentum.filter
        self._mom = np.hstack([np.array(mom.A()), np.array(mom.B())])
        self._xu = np.empty(ns + design.input_size)            # [x; u] of the conditioner
        self._u = self._xu[ns:]                                # its input [q; (q̇); τ_J]
        self._u_q, self._u_qd, self._u_tau = self._u[:n], self._u[n:2 * n], self._u[-n:]
        self._x = self._xu[:ns]
        self._yx = np.empty(4 * n + ns)                        # its [y; x⁺] = [q̂; q̂̇; q̂̈; τ̂_J; x⁺]
        self._y, self._tau_f, self._x_next = self._yx[:3 * n], self._yx[3 * n:4 * n], self._yx[4 * n:]
        self._xmu = np.empty(7 * n)                            # [x; u] of the momentum filter
        self._r, self._x_mom = self._xmu[:n], self._xmu[:3 * n]
        self._um = um = self._xmu[3 * n:]                      # its input [p; τ_g + Cᵀq̇; τ_J; τ_int]
        self._um_terms, self._um_tau, self._um_int = um[:2 * n], um[2 * n:3 * n], um[3 * n:]
        self._initial_momentum = estimator.momentum.initial_state
        # the torque model's step on [τ_rigid; q̂; q̂̇; q̂̈], τ_rigid = M q̂̈ + ID(q̂, q̂̇, 0) from the rigid-body terms
        # (one set of kinematics per sample); its output [τ_dyn; τ_int; next memory] goes to two buffers in turn, so
        # that the memory read in one step is the other buffer's
        torque = estimator.torque_model
        self._torque_step = torque.step_into
        self._initial_memory = torque.initial_memory
        self._tm_in = np.empty(4 * n)
        self._tau_rigid, self._qqdqdd = self._tm_in[:n], self._tm_in[n:]
        self._qdd_f = self._tm_in[3 * n:]
        self._outs = [torque.output_buffer() for _ in range(2)]
        self._state = self._tm_in[n:3 * n]                    # [q̂; q̂̇]
        terms = estimator.momentum.terms
        self._terms, self._rigid = terms.calc, terms.inverse_dynamics
        self._wrench = estimator.wrench.calc_jacobian
        self._estimate = estimator.wrench.estimate_buffer()
        rb = terms.terms                                       # its output buffer [p; τ_g + Cᵀq̇; vec(J)]
        self._rb_terms, self._jac = rb[:2 * n], rb[2 * n:].reshape(6, n)
        self._tau_ext = np.empty((2, n))
        self._tau_ext_jac, self._tau_ext_mom = self._tau_ext[0], self._tau_ext[1]
        self.reset()

    @classmethod
    def from_model(cls, model: TorqueModel | RobotDescription | str | Path, rate_hz: float | None = None,
                   cutoff_hz: float | Sequence[float] | None = None, gain: float | np.ndarray = DEFAULT_GAIN,
                   mapping: WrenchMapping = WrenchMapping(), velocity: str = "q", tau_filter: bool = True,
                   conditioning: CausalConditioning | None = None, max_step_jitter: float = 0.5
                   ) -> "OnlineEstimator":
        """An estimator for ``model`` (a :class:`TorqueModel`, a description, or a spec of
        :func:`~proprio.diagrams.estimation.load_torque_model`: robot name, YAML/URDF, identified ``.npz``, hybrid
        ``.pt``).

        Args:
            rate_hz: the sample rate [Hz] of the loop (a hybrid model's own rate by default; required otherwise).
            cutoff_hz: cutoff [Hz] of the causal filters, one or one per joint (a hybrid model's
                training ``data.cutoff_hz`` by default when it is a number; e.g. ``condition(previous_log).cutoff_hz``;
                required otherwise).
            gain: momentum observer K_O [1/s]. mapping: the wrench mapping (contact point, force-only, weights).
            velocity: ``"q"`` differentiates q; ``"measured"`` filters the robot's own q̇ (then :meth:`step` needs it).
            tau_filter: give τ_J the same low-pass (default; keeps prediction and measurement aligned).
            conditioning: a ready design instead of ``rate_hz``/``cutoff_hz``/``velocity``/``tau_filter``.
            max_step_jitter: accepted deviation of a sample's Δt from 1/rate_hz, as a fraction.
        """
        if isinstance(model, RobotDescription):
            model = RigidBodyTorqueModel(model)
        elif isinstance(model, (str, Path)):
            model = load_torque_model(model)
        if conditioning is None:
            rate = rate_hz if rate_hz is not None else getattr(model, "rate_hz", None)
            data = getattr(model, "data", None)
            trained = getattr(data, "cutoff_hz", None)
            cut = cutoff_hz if cutoff_hz is not None else None if isinstance(trained, str) else trained
            if rate is None or cut is None:
                raise ValueError("OnlineEstimator.from_model: give rate_hz [Hz] and cutoff_hz [Hz] (e.g. "
                                 "proprio.conditioning.condition(previous_log).cutoff_hz) for a rigid-body model or "
                                 "a hybrid model trained with cutoff_hz: auto")
            conditioning = causal_conditioning(float(rate), cut, model.description.n, velocity, tau_filter)
        return cls(WrenchEstimator(model, conditioning.time_step, gain, mapping, conditioning), max_step_jitter)

    def reset(self) -> None:
        """Forget the past: the next sample restarts the filters (steady state), the observers and the network."""
        self._t_prev = -math.inf
        self._started = False
        self._memory = self._initial_memory()
        self._turn = 0

    def _check(self, t: float, q: np.ndarray, tau_J: np.ndarray, qd: np.ndarray | None) -> None:
        n, u = self.n, self._u
        try:
            self._u_q[:] = q
        except (ValueError, TypeError):
            raise OnlineInputError(f"q: expected {n} joint positions [rad], got shape {np.shape(q)}") from None
        try:
            self._u_tau[:] = tau_J
        except (ValueError, TypeError):
            raise OnlineInputError(f"tau_J: expected {n} joint torques [N·m], got shape {np.shape(tau_J)}") from None
        if self._velocity:
            if qd is None:
                raise OnlineInputError("qd: this estimator filters the robot's own velocity (velocity='measured'); "
                                       "pass qd [rad/s]")
            try:
                self._u_qd[:] = qd
            except (ValueError, TypeError):
                raise OnlineInputError(f"qd: expected {n} joint velocities [rad/s], got shape {np.shape(qd)}") \
                    from None
        elif qd is not None:
            raise OnlineInputError("qd: this estimator differentiates q (velocity='q'); build it with "
                                   "velocity='measured' to use the robot's own q̇")
        if not math.isfinite(u @ u):
            for name, part in (("q", u[:n]), ("qd", u[n:2 * n] if self._velocity else None), ("tau_J", u[-n:])):
                if part is not None and not np.all(np.isfinite(part)):
                    bad = int(np.flatnonzero(~np.isfinite(part))[0])
                    raise OnlineInputError(f"{name}: non-finite value {part[bad]} at joint {bad + 1}")
            raise OnlineInputError("q, tau_J: values too large to be joint positions and torques")
        if not math.isfinite(t):
            raise OnlineInputError(f"t: non-finite time stamp {t}")
        if self._started:
            dt = t - self._t_prev
            if not dt > 0:
                raise OnlineInputError(f"t: time stamps must increase strictly, got t = {t!r} s after {self._t_prev!r} s")
            if abs(dt - self.time_step) > self.max_step_jitter * self.time_step:
                raise OnlineInputError(f"t: step {dt * 1e3:.4g} ms differs from the design step "
                                       f"{self.time_step * 1e3:.4g} ms by more than {self.max_step_jitter:.0%} (the "
                                       "filters assume a fixed rate); feed samples at rate_hz or call reset()")

    def step(self, t: float, q: np.ndarray, tau_J: np.ndarray, qd: np.ndarray | None = None) -> WrenchEstimate:
        """The estimate for one sample: time ``t`` [s], joint positions ``q`` [rad], measured link-side torques
        ``tau_J`` [N·m] and, with ``velocity="measured"``, the robot's own ``qd`` [rad/s]. Raises
        :class:`OnlineInputError` naming the field for a malformed sample (the state is left as it was)."""
        t = float(t)
        self._check(t, q, tau_J, qd)
        if not self._started:
            self._x[:] = self.design.initial_state(self._u)
        np.dot(self._cond, self._xu, out=self._yx)                  # [q̂; q̂̇; q̂̈; τ̂_J; x⁺]
        self._x[:] = self._x_next
        self._qqdqdd[:] = self._y
        tau_f = self._tau_f
        self._terms(self._state)
        self._tau_rigid[:] = self._rigid(self._qdd_f)
        out = self._outs[self._turn]
        self._turn ^= 1
        self._torque_step(self._memory, self._tm_in, out)
        _, tau_dyn, tau_int, self._memory = out
        np.subtract(tau_dyn, tau_f, out=self._tau_ext_jac)
        self._um_terms[:] = self._rb_terms
        self._um_tau[:] = tau_f
        self._um_int[:] = tau_int
        if not self._started:
            self._x_mom[:] = self._initial_momentum(self._um)
            self._started = True
        self._tau_ext_mom[:] = self._r                              # r_{k−1}: the filter's output before its update
        self._x_mom[:] = self._mom @ self._xmu
        self._t_prev = t
        v = self._wrench(self._jac, self._tau_ext, self._estimate).copy()
        v.flags.writeable = False
        return WrenchEstimate(t, v)
