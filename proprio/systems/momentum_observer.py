"""The rigid-body backbone of the estimator and De Luca's generalised-momentum observer (§3.1, the second way to
τ_ext in :mod:`proprio.systems.observers`) as Systems — thin wrappers of the laws below them:

* :class:`RigidBodyTermsSystem` — the RBD stage: τ_rigid, p, τ_g + Cᵀq̇ and J(q) at one sample from ONE plant
  context (:class:`proprio.rigid_body_terms.RigidBodyTerms`);
* :class:`MomentumObserver` — the residual r as the C++ discrete ``LinearSystem`` of
  :func:`proprio.momentum.momentum_filter` (the streaming estimator steps the same matrices; the batch form over
  samples is :func:`proprio.momentum.momentum_observer`).
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, LinearSystem, Multiplexer

from proprio.description import RobotDescription
from proprio.momentum import momentum_filter, momentum_initial_state
from proprio.rigid_body_terms import RigidBodyTerms

__all__ = ["RigidBodyTermsStep", "RigidBodyTermsSystem", "MomentumObserver"]


class RigidBodyTermsStep(LeafSystem):
    """:class:`RigidBodyTermsSystem`'s Python System: input ``state`` = ``[q; q̇; q̈]`` (3n, one stacked port),
    output ``terms`` = ``[τ_rigid; p; τ_g + Cᵀq̇; J (6n)]`` (:meth:`RigidBodyTerms.calc_into`). Direct
    feedthrough."""

    def __init__(self, terms: RigidBodyTerms):
        LeafSystem.__init__(self)
        n = self.n = terms.description.n
        self._terms = terms
        self._state = self.DeclareVectorInputPort("state", 3 * n)
        self.DeclareVectorOutputPort("terms", 9 * n, self._calc)
        self._out = terms.buffer()
        self._views = terms.split(self._out)

    def _calc(self, context, output) -> None:
        x, n = self._state.Eval(context), self.n
        self._terms.calc_into(x[:n], x[n:2 * n], x[2 * n:], *self._views)
        output.SetFromVector(self._out)


class RigidBodyTermsSystem(Diagram):
    """The model robot's rigid-body terms at one sample (the estimator's RBD stage)::

        q, qd, qdd ──▶ Multiplexer ──▶ RigidBodyTermsStep ──▶ Demultiplexer ──▶ tau_rigid, momentum_terms, jacobian

    Input ports (size n): ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²]. Output ports: ``tau_rigid`` (n) [N·m] the
    inverse dynamics with gravity; ``momentum_terms`` (2n) ``[p = M(q)q̇ (N·m·s); τ_g + Cᵀq̇ (N·m)]`` for
    :class:`MomentumObserver`; ``jacobian`` (6n) the Jacobian of ``contact_point`` [m, flange frame] (rows [ω; v],
    world frame, row-major) for :class:`~proprio.systems.observers.WrenchMap`. Direct feedthrough, no state."""

    def __init__(self, desc: RobotDescription, contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        Diagram.__init__(self)
        n = self.n = desc.n
        self.terms = RigidBodyTerms(desc, contact_point)
        builder = DiagramBuilder()
        state = builder.AddNamedSystem("state", Multiplexer([n, n, n]))
        step = builder.AddNamedSystem("terms", RigidBodyTermsStep(self.terms))
        split = builder.AddNamedSystem("split", Demultiplexer([n, 2 * n, 6 * n]))
        for i, name in enumerate(("q", "qd", "qdd")):
            builder.ExportInput(state.get_input_port(i), name)
        builder.Connect(state.get_output_port(), step.get_input_port())
        builder.Connect(step.get_output_port(), split.get_input_port())
        for i, name in enumerate(("tau_rigid", "momentum_terms", "jacobian")):
            builder.ExportOutput(split.get_output_port(i), name)
        builder.BuildInto(self)
        self.set_name("rigid_body")


class MomentumObserver(Diagram):
    """De Luca's generalised-momentum observer as a sub-Diagram, updated every ``time_step`` (the data rate)::

        momentum_terms [p; τ_g + Cᵀq̇], tau_meas, tau_int ──▶ Multiplexer ──▶ LinearSystem (C++, discrete) ──▶ tau_ext
                                                                           (:func:`~proprio.momentum.momentum_filter`)

    Input ports: ``momentum_terms`` (2n) from :class:`RigidBodyTermsSystem`, ``tau_meas`` (n) [N·m] (measured τ_J),
    ``tau_int`` (n) [N·m] (the model's non-rigid-body torque; connect zeros for a pure rigid-body model). Output
    port: ``tau_ext`` (n) [N·m], the residual r (the filter's state). Its wrench is
    :class:`~proprio.systems.observers.WrenchMap`'s ``wrench_momentum``. Same recursion as
    :func:`~proprio.momentum.momentum_observer`; call :meth:`set_initial_state` once the first sample is on the
    inputs (r then starts at 0 exactly as offline; without it the first step sees p_{−1} = β_{−1} = 0, a large
    kick). As for any Drake discrete state, the update at t_k is visible from the next step on, so the output at
    t_k is r_{k−1}.
    """

    def __init__(self, desc: RobotDescription, time_step: float, gain: float | np.ndarray = 100.0):
        Diagram.__init__(self)
        n = self.n = desc.n
        builder = DiagramBuilder()
        mux = self._mux = builder.AddNamedSystem("stack", Multiplexer([2 * n, n, n]))
        self.filter = builder.AddNamedSystem("filter", LinearSystem(*momentum_filter(n, time_step, gain),
                                                                    float(time_step)))
        for i, name in enumerate(("momentum_terms", "tau_meas", "tau_int")):
            builder.ExportInput(mux.get_input_port(i), name)
        builder.Connect(mux.get_output_port(), self.filter.get_input_port())
        builder.ExportOutput(self.filter.get_output_port(), "tau_ext")
        builder.BuildInto(self)
        self.set_name("momentum_observer")

    def set_initial_state(self, context: Context) -> None:
        """Set the filter state from the inputs ``context`` (this System's context) sees now: the first sample."""
        u0 = np.asarray(self._mux.get_output_port().Eval(self.GetSubsystemContext(self._mux, context)))
        self.GetMutableSubsystemContext(self.filter, context).get_mutable_discrete_state_vector().SetFromVector(
            momentum_initial_state(u0))
