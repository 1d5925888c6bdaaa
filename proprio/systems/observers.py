"""External-wrench observers at the flange, from joint torques (§3.1 eq. 3.8–3.14; De Luca's momentum observer).

Conventions (DESIGN.md): the measured link-side torque is ``τ_J = τ_rbd(q, q̇, q̈) + τ_int − Jᵀ f_ext`` where
``τ_int`` is what a model adds to the rigid body (link friction, a learned residual) and ``f_ext`` is the wrench
the environment exerts ON the robot at the flange, world frame, order ``[fx, fy, fz, mx, my, mz]`` (N, N·m). So
the external joint torque is

    τ_ext = Jᵀ f_ext = τ_dyn − τ_J,        τ_dyn = τ_rbd + τ_int                      (eq. 3.10)
    f_ext = J⁻ᵀ τ_ext                                                                   (eq. 3.11–3.12)

Two ways to get τ_ext:

* :class:`JacobianWrenchObserver` — direct: τ_ext = τ_dyn − τ_J with τ_dyn from a dynamics model fed with filtered
  (q, q̇, q̈). Needs accelerations, no memory, no lag.
* :class:`~proprio.systems.momentum_observer.MomentumObserver` — De Luca's generalised-momentum residual (needs no
  q̈), a first-order low-pass of τ_ext with time constant 1/K_O per joint; in :mod:`proprio.systems.momentum_observer`.

As Systems (one per stage, C++ where the work is linear): :class:`JacobianWrenchObserver` (τ_dyn − τ_J, a
``MatrixGain``), the momentum observer (the recursion as a discrete ``LinearSystem`` on the rigid-body terms p,
τ_g + Cᵀq̇ of the RBD stage, :mod:`proprio.systems.momentum_observer`) and :class:`WrenchMap`, which maps both τ̂_ext
to wrenches with ONE Jacobian (the RBD stage's) and ONE factorisation per step — a thin wrapper of the solve law
:class:`~proprio.wrench_solve.WrenchSolver`, which :mod:`proprio.online` calls directly.

The Jacobian pseudo-inverse (eq. 3.12, the arm is redundant: 7 equations, 6 or 3 unknowns) is the weighted,
adaptively damped least-squares law of :mod:`proprio.wrench_solve` (re-exported here): ``WrenchMapping`` its options,
``WrenchSolver`` its per-step form, ``wrench_from_joint_torque`` / ``jacobian_wrench`` over samples — one compiled
kernel for all.
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, MatrixGain, Multiplexer

from proprio.description import RobotDescription
from proprio.plant import DrakeRobot
from proprio.wrench_solve import WrenchMapping, WrenchSolver, jacobian_wrench, wrench_from_joint_torque

__all__ = ["WrenchMapping", "wrench_from_joint_torque", "WrenchSolver", "jacobian_wrench", "WrenchMapStep", "WrenchMap",
           "JacobianWrenchObserver"]


class WrenchMapStep(LeafSystem):
    """:class:`WrenchMap`'s Python System: input ``inputs`` = ``[q or vec(J); τ̂_ext,1; …; τ̂_ext,m]`` (one stacked port: each
    input evaluation from Python costs about a microsecond), output ``estimate`` (:meth:`WrenchMap.calc`)."""

    def __init__(self, owner: "WrenchMap"):
        LeafSystem.__init__(self)
        n, m = owner.n, len(owner.sources)
        self._owner, self._n, self._m = owner, n, m
        self._k = 6 * n if owner.jacobian_input else n
        self._inputs = self.DeclareVectorInputPort("inputs", self._k + m * n)
        self.DeclareVectorOutputPort("estimate", 6 * m + 2 + m * n, self._calc)
        self._out = owner.estimate_buffer()

    def _calc(self, context, output) -> None:
        x, k = self._inputs.Eval(context), self._k
        tau_ext = x[k:].reshape(self._m, self._n)
        if self._owner.jacobian_input:
            self._owner.calc_jacobian(x[:k].reshape(6, self._n), tau_ext, self._out)
        else:
            self._owner.calc(x[:k], tau_ext, self._out)
        output.SetFromVector(self._out[0])


class WrenchMap(Diagram):
    """The Cartesian mapping of eq. 3.12 shared by the observers: ``f̂ = J⁻ᵀ(q) τ̂_ext`` for each observer's τ̂_ext,
    with ONE Jacobian (Drake's ``CalcJacobianSpatialVelocity`` on a cached plant context) and ONE eigen-decomposition
    (:class:`WrenchSolver`) per step for all of them.

    Input ports: ``q`` (n) [rad] — or, with ``jacobian_input``, ``jacobian`` (6n) the contact point's Jacobian (rows
    [ω; v], world frame, row-major, e.g. :class:`MomentumObserver`'s) —; ``tau_ext_<source>`` (n) [N·m] for each name
    in ``sources`` (default ``("jacobian", "momentum")``). Output ports: ``estimate`` (6m + 2 + mn), all of it stacked
    ``[wrench_<s>…, manipulability, unreliable, tau_ext_<s>…]`` — the one port a logger needs — and, split from it in
    C++, ``wrench_<source>`` (6) [fx, fy, fz, mx, my, mz] on the robot at the contact point, world frame (N, N·m;
    moment 0 in force-only mode); ``manipulability`` (1) = √det(J W Jᵀ); ``unreliable`` (1) 1.0 when σ_min <
    ``mapping.sigma_threshold`` else 0.0. Inside: ``Multiplexer`` → :class:`WrenchMapStep` → ``Demultiplexer``.
    """

    def __init__(self, desc: RobotDescription, mapping: WrenchMapping = WrenchMapping(),
                 sources: tuple[str, ...] = ("jacobian", "momentum"), jacobian_input: bool = False):
        Diagram.__init__(self)
        n, m = desc.n, len(sources)
        self.n, self.sources, self.jacobian_input = n, tuple(sources), jacobian_input
        self._arm = None if jacobian_input else DrakeRobot(desc)   # (with a Jacobian input, no plant of its own)
        self._solver = WrenchSolver(mapping, n)
        self._contact = np.asarray(mapping.contact_point, dtype=float)
        k = 6 * n if jacobian_input else n
        builder = DiagramBuilder()
        stack = builder.AddNamedSystem("stack", Multiplexer([k] + [n] * m))
        step = builder.AddNamedSystem("solve", WrenchMapStep(self))
        split = builder.AddNamedSystem("split", Demultiplexer([6] * m + [1, 1, m * n]))
        builder.ExportInput(stack.get_input_port(0), "jacobian" if jacobian_input else "q")
        for i, s in enumerate(self.sources):
            builder.ExportInput(stack.get_input_port(1 + i), f"tau_ext_{s}")
        builder.Connect(stack.get_output_port(), step.get_input_port())
        builder.Connect(step.get_output_port(), split.get_input_port())
        builder.ExportOutput(step.get_output_port(), "estimate")
        for i, s in enumerate(self.sources):
            builder.ExportOutput(split.get_output_port(i), f"wrench_{s}")
        builder.ExportOutput(split.get_output_port(m), "manipulability")
        builder.ExportOutput(split.get_output_port(m + 1), "unreliable")
        builder.BuildInto(self)
        self.set_name("wrench")

    def estimate_buffer(self) -> tuple[np.ndarray, ...]:
        """A preallocated ``estimate`` vector with its views ``(vector, wrenches [m,6], [manipulability,
        unreliable], τ̂_ext [m,n])``, for the ``out`` argument of :meth:`calc` / :meth:`calc_jacobian`."""
        n, m = self.n, len(self.sources)
        v = np.empty(6 * m + 2 + m * n)
        return v, v[:6 * m].reshape(m, 6), v[6 * m:6 * m + 2], v[6 * m + 2:].reshape(m, n)

    def calc(self, q: np.ndarray, tau_ext: np.ndarray, out: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
        """The ``estimate`` vector for ``q [n]`` and ``tau_ext [m,n]`` (one row per source) — the step function
        (written into ``out``, an :meth:`estimate_buffer`, when given)."""
        if self._arm is None:
            raise ValueError("WrenchMap: built with jacobian_input=True; call calc_jacobian(J, tau_ext)")
        return self.calc_jacobian(self._arm.flange_jacobian(q, self._contact), tau_ext, out)

    def calc_jacobian(self, jac: np.ndarray, tau_ext: np.ndarray, out: tuple[np.ndarray, ...] | None = None
                      ) -> np.ndarray:
        """The same from the contact point's Jacobian ``jac [6,n]`` (rows [ω; v], world) — the step function with
        ``jacobian_input`` (written into ``out``, an :meth:`estimate_buffer`, when given; a new vector otherwise)."""
        vector, wrench, flags, tau = self.estimate_buffer() if out is None else out
        self._solver.solve_into(jac, tau_ext, wrench, flags)
        tau[:] = tau_ext
        return vector


class JacobianWrenchObserver(Diagram):
    """The direct observer's joint-space part, τ̂_ext = τ_dyn − τ_meas (eq. 3.10), in C++ (``Multiplexer`` →
    ``MatrixGain [I −I]``): direct feedthrough, no state, no lag. Its wrench is :class:`WrenchMap`'s
    ``wrench_jacobian`` (the same solver as :func:`jacobian_wrench`).

    Input ports (size n): ``tau_dyn`` [N·m] (model torque), ``tau_meas`` [N·m] (measured τ_J).
    Output port: ``tau_ext`` (n) [N·m].
    """

    def __init__(self, n: int):
        Diagram.__init__(self)
        builder = DiagramBuilder()
        mux = builder.AddNamedSystem("stack", Multiplexer([n, n]))
        diff = builder.AddNamedSystem("difference", MatrixGain(np.hstack([np.eye(n), -np.eye(n)])))
        builder.Connect(mux.get_output_port(), diff.get_input_port())
        builder.ExportInput(mux.get_input_port(0), "tau_dyn")
        builder.ExportInput(mux.get_input_port(1), "tau_meas")
        builder.ExportOutput(diff.get_output_port(), "tau_ext")
        builder.BuildInto(self)
        self.set_name("jacobian_observer")
