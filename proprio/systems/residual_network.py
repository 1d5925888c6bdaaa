"""The learned residual of the hybrid model (§4.2, eq. 4.29/4.30) as a Drake System with streaming inference — the
residual-network stage of the estimation Diagram (DESIGN.md: features → RBD backbone τ_RBD → residual network τ_NN →
wrench observer).

    tau_rbd, q, qd, qdd ──▶ ResidualNetworkSystem ──▶ tau_nn      (τ_NN, the network's own output)
                                                  └─▶ tau_hybrid  (τ_HYB = τ_RBD + τ_NN, a Drake Adder)

A discrete-time system at the model's data rate (``1 / model.cfg.rate_hz``, the rate after the §4.4 decimation) in
the usual state-space form ``y_k = g(x_k, u_k)``, ``x_{k+1} = f(x_k, u_k)``:

* the state x (``memory``, held by a C++ ``ZeroOrderHold``) is the rotational-displacement encoder's state
  (direction, signed running extremum and reversal point per joint) and the network's recurrent state (h₁, c₁, h₂, c₂
  of the LSTM; none for MLP-7);
* one step — advance the encoder with q_k, build vec(τ_RBD, q, q̇, q̈, r)_k, run the network one sample — gives both
  the output y_k and the next state, as ONE vector output of a stateless Python System (Drake caches it per
  context, so the network runs once per sample: the loggers and the hold's update at t_k read the same value);
* the outputs are **direct feedthrough**: at a sample time t_k they are the prediction for the inputs of t_k, with
  no sample of latency, so an observer comparing τ_HYB with the same instant's τ_J sees matched samples;
* the hold samples the next state at every t_k (a periodic discrete update in C++, no Python event).

Because the outputs depend on the inputs at once, a loop from ``tau_nn`` back into ``q``/``qd``/``qdd``/``tau_rbd``
needs a state somewhere on the path (e.g. the plant, or a ``ZeroOrderHold``), as for any feedthrough system. Between
sample times the outputs are not meaningful (they would apply one more step to interpolated inputs): sample them at
the model rate, as the estimation diagram's loggers do.

The step is the law :class:`~proprio.learning.streaming.ResidualNetworkCore` (the encoder and the network as compiled
float64 kernels, the same weights and equations as the torch model, equal to it to rounding — a torch call per
sample costs ≈10× more overhead than the arithmetic), which the streaming estimator calls too. Transformers have no
streaming form and are rejected.
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Adder, Demultiplexer, Multiplexer, ZeroOrderHold

from proprio.learning.models import HybridModel
from proprio.learning.streaming import ResidualNetworkCore

__all__ = ["ResidualNetworkStep", "ResidualNetworkSystem", "AddResidualNetwork"]


class ResidualNetworkStep(LeafSystem):
    """One step of the network as a stateless System (the state comes back through ``memory``): input ``inputs`` =
    ``[τ_rbd; q; q̇; q̈; memory]`` (4n: N·m, rad, rad/s, rad/s², then the previous step's memory, ``1 + 3n +
    state_size``); output ``step`` = ``[τ_NN (n) N·m; next memory]`` (:meth:`~proprio.learning.streaming.
    ResidualNetworkCore.step_into`). One stacked input: each input evaluation from Python costs about a microsecond."""

    def __init__(self, owner: ResidualNetworkCore):
        super().__init__()
        n, size = owner.n, owner.memory_size
        self._owner, self._k = owner, 4 * n
        self._inputs = self.DeclareVectorInputPort("inputs", 4 * n + size)
        self.DeclareVectorOutputPort("step", n + size, self._calc)
        self._out = np.empty(n + size)
        self._tau, self._next = self._out[:n], self._out[n:]

    def _calc(self, context, output) -> None:
        x, k = self._inputs.Eval(context), self._k
        self._owner.step_into(x[k:], x[:k], self._tau, self._next)
        output.SetFromVector(self._out)


class ResidualNetworkSystem(Diagram):
    """A trained :class:`~proprio.learning.models.HybridModel` run online, one sample per period.

    Args:
        model: a trained MLP-7 or LSTM hybrid/standalone model.
        period_s: update period [s]; default ``1 / model.cfg.rate_hz`` (the model's data rate).

    Input ports (size n each), the network's features but r (which it encodes from q itself): ``tau_rbd`` [N·m] (the
    backbone's torque τ_RBD at the same sample), ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²]. Output ports (size n,
    direct feedthrough): ``tau_nn`` [N·m] = τ_NN, the network's own output (a hybrid's residual; a standalone model's
    torque); ``tau_hybrid`` [N·m] = τ_RBD + τ_NN for a hybrid model (a C++ ``Adder``), τ_NN for a standalone one.

    Inside, one Python System per step and C++ for the rest::

        Multiplexer(tau_rbd, q, qd, qdd, memory) ─▶ ResidualNetworkStep ─▶ Demultiplexer ─▶ tau_nn
                                          ▲                         └─ next memory ─▶ ZeroOrderHold (period) ─┐
                                          └───────────────────────────────────────────────────────────────────┘
        Adder(tau_rbd, tau_nn) ─▶ tau_hybrid

    The memory ``[started, encoder state (3n), network state]`` is the hold's discrete state (zeros at start:
    ``started`` = 0 makes the first step start the encoder at the first q and the LSTM at zero state).
    """

    def __init__(self, model: HybridModel, period_s: float | None = None):
        Diagram.__init__(self)
        self.core = core = ResidualNetworkCore(model)
        self.stepper, self.encoder, self.n, self.memory_size = core.stepper, core.encoder, core.n, core.memory_size
        n, size = self.n, self.memory_size
        self.period_s = float(period_s) if period_s is not None else 1.0 / model.cfg.rate_hz
        if not self.period_s > 0:
            raise ValueError(f"ResidualNetworkSystem: period_s must be > 0 s, got {self.period_s}")
        builder = DiagramBuilder()
        inputs = builder.AddNamedSystem("inputs", Multiplexer([n] * 4 + [size]))
        step = builder.AddNamedSystem("step", ResidualNetworkStep(core))
        split = builder.AddNamedSystem("split", Demultiplexer([n, size]))
        hold = builder.AddNamedSystem("memory", ZeroOrderHold(self.period_s, size))
        for i, name in enumerate(("tau_rbd", "q", "qd", "qdd")):
            builder.ExportInput(inputs.get_input_port(i), name)
        builder.Connect(inputs.get_output_port(), step.get_input_port())
        builder.Connect(step.get_output_port(), split.get_input_port())
        builder.Connect(split.get_output_port(1), hold.get_input_port())
        builder.Connect(hold.get_output_port(), inputs.get_input_port(4))
        builder.ExportOutput(split.get_output_port(0), "tau_nn")
        if model.cfg.hybrid:
            total = builder.AddNamedSystem("tau_hybrid", Adder(2, n))
            builder.ConnectInput("tau_rbd", total.get_input_port(0))
            builder.Connect(split.get_output_port(0), total.get_input_port(1))
            builder.ExportOutput(total.get_output_port(), "tau_hybrid")
        else:
            builder.ExportOutput(split.get_output_port(0), "tau_hybrid")
        builder.BuildInto(self)
        self.set_name("residual_network")


def AddResidualNetwork(builder: DiagramBuilder, model: HybridModel, period_s: float | None = None,
                       name: str = "residual_network") -> ResidualNetworkSystem:
    """Add a :class:`ResidualNetworkSystem` for ``model`` to ``builder`` (ports unconnected) and return it."""
    system = builder.AddSystem(ResidualNetworkSystem(model, period_s))
    system.set_name(name)
    return system
