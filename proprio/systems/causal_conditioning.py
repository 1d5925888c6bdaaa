"""The causal signal-conditioning stage of the online estimator as a Drake System (C++ primitives only).

    q ──────────┐                                                   ┌──▶ q     (q̂, rad)
    [qd] ───────┼─▶ Multiplexer ─▶ LinearSystem (discrete, period h) ─▶ Demultiplexer ─┼──▶ qd    (q̂̇, rad/s)
    tau_meas ───┘        u                 x⁺ = A x + B u, y = C x + D u             ├──▶ qdd   (q̂̈, rad/s²)
                                                                                    └──▶ tau_meas (τ̂_J, N·m)

The filter is :func:`proprio.causal_conditioning.causal_conditioning` (a 2nd-order Butterworth state-variable filter
per joint and channel; its docstring says how it differs from the offline zero-phase path: a low-frequency lag of
√2/ω_c on every channel, τ_J included so that prediction and measurement stay aligned). Outputs are direct
feedthrough (``D ≠ 0``): at a sample time t_k they already include the sample u_k; the discrete update at t_k
then advances the state. :meth:`CausalConditioner.set_initial_state` starts the filter in the steady state of the
first sample (no start-up transient), as the streaming estimator (:mod:`proprio.online`) does.
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Context, Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, LinearSystem, Multiplexer

from proprio.causal_conditioning import CausalConditioning

__all__ = ["CausalConditioner"]


class CausalConditioner(Diagram):
    """:class:`~proprio.causal_conditioning.CausalConditioning` as a sub-Diagram with named ports.

    Input ports (size n): ``q`` [rad], ``qd`` [rad/s] (only with ``design.velocity == "measured"``), ``tau_meas``
    [N·m]. Output ports (size n): ``q``, ``qd``, ``qdd``, ``tau_meas`` — the conditioned (lagged) signals.
    """

    def __init__(self, design: CausalConditioning):
        Diagram.__init__(self)
        self.design = design
        n = design.n
        inputs = ["q", "qd", "tau_meas"] if design.velocity == "measured" else ["q", "tau_meas"]
        builder = DiagramBuilder()
        mux = builder.AddNamedSystem("inputs", Multiplexer([n] * len(inputs)))
        self.filter = builder.AddNamedSystem("filter", LinearSystem(design.A, design.B, design.C, design.D,
                                                                     design.time_step))
        demux = builder.AddNamedSystem("outputs", Demultiplexer([n] * 4))
        for i, name in enumerate(inputs):
            builder.ExportInput(mux.get_input_port(i), name)
        builder.Connect(mux.get_output_port(), self.filter.get_input_port())
        builder.Connect(self.filter.get_output_port(), demux.get_input_port())
        for i, name in enumerate(("q", "qd", "qdd", "tau_meas")):
            builder.ExportOutput(demux.get_output_port(i), name)
        builder.BuildInto(self)
        self.set_name("conditioner")
        self._mux = mux

    def set_initial_state(self, context: Context) -> None:
        """Put the filter in the steady state of the inputs ``context`` sees now (the first sample).
        ``context`` is this System's context (e.g. ``GetMyContextFromRoot`` of a root context)."""
        u0 = self._mux.get_output_port().Eval(self.GetSubsystemContext(self._mux, context))
        self.GetMutableSubsystemContext(self.filter, context).get_mutable_discrete_state_vector().SetFromVector(
            self.design.initial_state(np.asarray(u0)))
