"""Streaming wrench estimation for the real robot: one sample in, one estimate out, from your own control loop.

For users who drive the estimator from their own loop (KUKA FRI at 1 kHz, a ROS 2 callback) rather than a Drake
``Simulator``::

    from proprio.online import OnlineEstimator

    est = OnlineEstimator.from_model("iiwa14_identified", rate_hz=1000.0, cutoff_hz=10.0)
    while running:                                   # every 1 ms
        t, q, tau_J = robot.read()                   # s, rad [7], N·m [7] (link-side torque sensors)
        w = est.step(t, q, tau_J)                    # or est.step(t, q, tau_J, qd) with velocity="measured"
        f = w.jacobian[:3]                           # N, on the robot at the flange origin, world frame

It chains the laws of the estimation Diagram (:class:`proprio.diagrams.estimation.WrenchEstimator`) directly behind
its input validation, with no Drake Context per sample: the causal conditioner's and the momentum observer's
matrices stepped by :class:`~proprio.discrete_lti.DiscreteLti`, the rigid-body terms from one plant context
(:class:`~proprio.rigid_body_terms.RigidBodyTerms`), the model's torque step (friction, + the network of a hybrid
model: :class:`~proprio.learning.streaming.ResidualNetworkCore`) and the wrench solve
(:class:`~proprio.wrench_solve.WrenchSolver`) — the functions the Diagram's Systems wrap, so the numbers are the
Diagram's (tests: to 1e-10) and there is no second copy of any stage. The compiled kernels are compiled (or loaded
from numba's cache) and run once when the estimator is built, so the first control cycle is not the compile. Inputs
are validated at the boundary (shape, finiteness, time strictly increasing at the design rate); one estimator serves
one robot from one thread. For a hard real-time loop call ``gc.freeze()`` once after building it (the interpreter's
full collections otherwise scan every object torch and Drake made at import: a pause of milliseconds every ~10³
steps).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from proprio.causal_conditioning import CausalConditioning, causal_conditioning
from proprio.description import RobotDescription
from proprio.diagrams.estimation import (DEFAULT_GAIN, RigidBodyTorqueModel, TorqueModel, WrenchEstimator,
                                         load_torque_model)
from proprio.discrete_lti import DiscreteLti
from proprio.momentum import momentum_filter, momentum_initial_state
from proprio.rigid_body_terms import RigidBodyTerms
from proprio.wrench_solve import WrenchMapping, WrenchSolver

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
        # the laws of the Diagram's stages, each with its own explicit state
        self._conditioner = DiscreteLti(design.A, design.B, design.C, design.D)
        self._rigid = RigidBodyTerms(self.description, estimator.mapping.contact_point)
        self._torque = estimator.model.torque_step()
        self._momentum = DiscreteLti(*momentum_filter(n, self.time_step, estimator.gain))
        self._solver = WrenchSolver(estimator.mapping, n)
        # the validated sample [q; (q̇); τ_J] — the conditioner's input
        self._sample = np.empty(design.input_size)
        self._q, self._tau = self._sample[:n], self._sample[-n:]
        self._qd = self._sample[n:2 * n] if self._velocity else None
        # signals in the layouts the laws read: a = [τ_rigid; q̂; q̂̇; q̂̈; τ̂_J] (the torque step reads its first 4n),
        # m = [p; τ_g + Cᵀq̇; τ̂_J; τ_int] (the momentum filter's input), the torque step's [τ_dyn; τ_int], J, and
        # the estimate [wrenches (2×6); manipulability, unreliable; τ̂_ext,jacobian; τ̂_ext,momentum = r]
        a, m = self._a, self._m = np.empty(5 * n), np.empty(4 * n)
        self._conditioned, self._rigid_in = a[n:], (a[n:2 * n], a[2 * n:3 * n], a[3 * n:4 * n])
        self._torque_in, self._tau_hat, self._tau_rigid = a[:4 * n], a[4 * n:], a[:n]
        self._momentum_terms, self._m_tau, self._m_int = m[:2 * n], m[2 * n:3 * n], m[3 * n:]
        self._torques = np.empty(2 * n)
        self._tau_dyn, self._tau_int = self._torques[:n], self._torques[n:]
        self._jac = np.empty(6 * n)
        self._jac_matrix = self._jac.reshape(6, n)
        v = self._v = np.empty(14 + 2 * n)
        self._wrench, self._flags, self._tau_ext = v[:12].reshape(2, 6), v[12:14], v[14:].reshape(2, n)
        self._tau_ext_jacobian, self._r = v[14:14 + n], v[14 + n:]
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
        self._memory = [self._torque.initial_memory(), np.empty(self._torque.memory_size)]

    def _check(self, t: float, q: np.ndarray, tau_J: np.ndarray, qd: np.ndarray | None) -> None:
        n, u = self.n, self._sample
        try:
            self._q[:] = q
        except (ValueError, TypeError):
            raise OnlineInputError(f"q: expected {n} joint positions [rad], got shape {np.shape(q)}") from None
        try:
            self._tau[:] = tau_J
        except (ValueError, TypeError):
            raise OnlineInputError(f"tau_J: expected {n} joint torques [N·m], got shape {np.shape(tau_J)}") from None
        if self._velocity:
            if qd is None:
                raise OnlineInputError("qd: this estimator filters the robot's own velocity (velocity='measured'); "
                                       "pass qd [rad/s]")
            try:
                self._qd[:] = qd
            except (ValueError, TypeError):
                raise OnlineInputError(f"qd: expected {n} joint velocities [rad/s], got shape {np.shape(qd)}") \
                    from None
        elif qd is not None:
            raise OnlineInputError("qd: this estimator differentiates q (velocity='q'); build it with "
                                   "velocity='measured' to use the robot's own q̇")
        if not math.isfinite(u @ u):
            for name, part in (("q", u[:n]), ("qd", self._qd), ("tau_J", u[-n:])):
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
        :class:`OnlineInputError` naming the field for a malformed sample (the state is left as it was).

        The Diagram's step at the sample, law by law: the outputs from the states before the sample (as the replayed
        Diagram's logger sees them at t), then each stage's update."""
        t = float(t)
        self._check(t, q, tau_J, qd)
        first = not self._started
        if first:                                     # the conditioner in the steady state of the first sample
            self._conditioner.x[:] = self.design.initial_state(self._sample)
        self._conditioner.step_into(self._sample, self._conditioned)
        self._rigid.calc_into(*self._rigid_in, self._tau_rigid, self._momentum_terms, self._jac)
        memory = self._memory
        self._torque.step_into(self._torque_in, memory[0], self._torques, memory[1])
        memory.reverse()
        np.subtract(self._tau_dyn, self._tau_hat, out=self._tau_ext_jacobian)
        self._m_tau[:] = self._tau_hat
        self._m_int[:] = self._tau_int
        if first:                                     # the momentum observer at r = 0
            self._momentum.x[:] = momentum_initial_state(self._m)
            self._started = True
        self._momentum.step_into(self._m, self._r)
        self._solver.solve_into(self._jac_matrix, self._tau_ext, self._wrench, self._flags)
        self._t_prev = t
        v = self._v.copy()
        v.flags.writeable = False
        return WrenchEstimate(t, v)
