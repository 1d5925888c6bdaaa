"""The learned residual of the hybrid model (§4.2, eq. 4.29/4.30) as a Drake System with streaming inference.

    q, qd, qdd, tau_rbd ──▶ ResidualNetworkSystem ──▶ tau_hybrid   (τ_HYB = τ_RBD + τ_NN)
                                                  └─▶ tau_residual (τ_HYB − τ_RBD)

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

Because the outputs depend on the inputs at once, a loop from ``tau_hybrid`` back into ``q``/``qd``/``qdd``/
``tau_rbd`` needs a state somewhere on the path (e.g. the plant, or a ``ZeroOrderHold``), as for any feedthrough
system. Between sample times the outputs are not meaningful (they would apply one more step to interpolated
inputs): sample them at the model rate, as the estimation diagram's loggers do.

The step runs the model as float64 numpy (:class:`~proprio.learning.models.StreamingStepper`, the same weights and
equations as the torch model, equal to it to rounding): a torch call per sample costs ≈10× more overhead than the
arithmetic. Transformers have no streaming form and are rejected.
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, MatrixGain, Multiplexer, ZeroOrderHold

from proprio.learning.features import ReversalEncoder
from proprio.learning.models import HybridModel, StreamingStepper

__all__ = ["ResidualNetworkCore", "MemoryViews", "ResidualNetworkStep", "ResidualNetworkSystem", "AddResidualNetwork"]


class ResidualNetworkCore:
    """The per-sample computation of the residual network, shared by the Systems (:class:`ResidualNetworkSystem`,
    the hybrid torque model's) and the streaming estimator: ``step_stacked(memory, [τ_rbd; q; q̇; q̈]) ->
    [τ_hybrid; next memory]``, a pure function of its arguments. The memory is ``[started, encoder state (3n),
    network state]``; zeros (``started`` = 0) start the encoder at the first q and the LSTM at zero state.
    (The stepper's scratch buffers make one core unsafe to share between threads.)"""

    def __init__(self, model: HybridModel):
        if not model.cfg.streamable:
            raise ValueError(f"ResidualNetworkSystem: {model.cfg.label()} has no streaming form (Transformer); "
                             "use an MLP-7 or LSTM model")
        cfg = model.cfg
        self.stepper = StreamingStepper(model)
        self.n = cfg.n_joints
        self.encoder = ReversalEncoder(self.n, cfg.reversal_deadband_deg, cfg.r_max_deg)
        self._n_net = self.stepper.state_size
        self.memory_size = 1 + 3 * self.n + self._n_net
        x = self.stepper.features                                    # the LSTM's own input buffer, if it has one
        self._x4, self._r = (None, None) if x is None else (x[:4 * self.n], x[4 * self.n:])

    def initial_memory(self) -> np.ndarray:
        """The memory before the first sample (``started`` = 0: the encoder starts at the first q)."""
        return np.zeros(self.memory_size)

    def step_parts(self, memory: np.ndarray, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One sample: ``(τ_hybrid (n) N·m, encoder state, network state)`` — the next memory is
        ``[1, encoder state, network state]`` — from the memory and the stacked inputs ``[τ_rbd; q; q̇; q̈]`` at t_k
        (neither argument is modified)."""
        n = self.n
        q = inputs[n:2 * n]
        if memory[0] > 0:
            enc, net_state = memory[1:1 + 3 * n], memory[1 + 3 * n:]
        else:
            enc, net_state = self.encoder.initial_state(q), np.zeros(self._n_net)
        r, enc = self.encoder.step_state(enc, q)
        tau, net_state = self.stepper.step(inputs, net_state, r)
        return tau, enc, net_state

    def memory_views(self, memory: np.ndarray) -> "MemoryViews":
        """The views of a memory vector that :meth:`step_views` reads and writes (make them once per buffer)."""
        return MemoryViews(self, memory)

    def step_into(self, memory: np.ndarray, inputs: np.ndarray, tau_out: np.ndarray, memory_out: np.ndarray
                  ) -> None:
        """:meth:`step_parts` into preallocated arrays: τ_hybrid [n] N·m into ``tau_out`` and the next memory into
        ``memory_out`` (which must not alias ``memory``)."""
        self.step_views(self.memory_views(memory), inputs, tau_out, self.memory_views(memory_out))

    def step_views(self, memory: "MemoryViews", inputs: np.ndarray, tau_out: np.ndarray, memory_out: "MemoryViews"
                   ) -> None:
        """:meth:`step_into` on :meth:`memory_views` of the memory and the next memory (the per-sample Systems' path).
        An LSTM reading all five feature blocks runs without allocation (the encoder writes r straight into the
        network's input buffer); other models through :meth:`step_parts`."""
        out = memory_out.vector
        if self._x4 is None:
            tau_out[:], out[1:1 + 3 * self.n], out[1 + 3 * self.n:] = self.step_parts(memory.vector, inputs)
            out[0] = 1.0
            return
        n = self.n
        q = inputs[n:2 * n]
        self._x4[:] = inputs
        if memory.vector[0] > 0:
            enc, net_state = memory.encoder, memory.network
        else:
            enc = self.encoder.initial_state(q)
            net_state = self.stepper.split_state(np.zeros(self._n_net))
        self.encoder.step_into(enc, q, memory_out.encoder, self._r, memory_out.encoder_parts)
        out[0] = 1.0
        self.stepper.step_split(net_state, memory_out.network, tau_out)

    def step_stacked(self, memory: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """:meth:`step_parts` stacked: ``[τ_hybrid (n) N·m; next memory]``."""
        out = np.empty(self.n + self.memory_size)
        self.step_into(memory, inputs, out[:self.n], out[self.n:])
        return out


class MemoryViews:
    """A :class:`ResidualNetworkCore` memory vector ``[started, encoder state (3n), network state]`` and its views:
    ``encoder`` (3n), ``encoder_parts`` (d, d·e, a) and ``network`` (the LSTM's h₁, c₁, h₂, c₂) — made once per
    buffer, as each slice costs about as much as a small numpy operation."""
    __slots__ = ("vector", "encoder", "encoder_parts", "network")

    def __init__(self, core: ResidualNetworkCore, vector: np.ndarray):
        n = core.n
        self.vector, self.encoder = vector, vector[1:1 + 3 * n]
        self.encoder_parts = core.encoder.split_state(self.encoder)
        net = vector[1 + 3 * n:]
        self.network = core.stepper.split_state(net) if core.stepper.features is not None else net


class ResidualNetworkStep(LeafSystem):
    """One step of the network as a stateless System (the state comes back through ``memory``): inputs ``inputs``
    = ``[τ_rbd; q; q̇; q̈]`` (4n: N·m, rad, rad/s, rad/s²) and ``memory`` (the previous step's, ``1 + 3n +
    state_size``); output ``step`` = ``[τ_hybrid (n) N·m; next memory]`` (:meth:`ResidualNetworkCore.step_stacked`).
    Two stacked inputs, not five: each input evaluation from Python costs about a microsecond."""

    def __init__(self, owner: ResidualNetworkCore):
        super().__init__()
        n, size = owner.n, owner.memory_size
        self._owner = owner
        self._inputs = self.DeclareVectorInputPort("inputs", 4 * n)
        self._memory = self.DeclareVectorInputPort("memory", size)
        self.DeclareVectorOutputPort("step", n + size, self._calc)
        self._out = np.empty(n + size)
        self._tau, self._next = self._out[:n], owner.memory_views(self._out[n:])

    def _calc(self, context, output) -> None:
        self._owner.step_views(self._owner.memory_views(self._memory.Eval(context)), self._inputs.Eval(context),
                               self._tau, self._next)
        output.SetFromVector(self._out)


class ResidualNetworkSystem(Diagram):
    """A trained :class:`~proprio.learning.models.HybridModel` run online, one sample per period.

    Args:
        model: a trained MLP-7 or LSTM hybrid/standalone model.
        period_s: update period [s]; default ``1 / model.cfg.rate_hz`` (the model's data rate).

    Input ports (size n each): ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²], ``tau_rbd`` [N·m] (the backbone's
    torque at the same sample). Output ports (size n, direct feedthrough): ``tau_hybrid`` [N·m] = τ_RBD + τ_NN for a
    hybrid model (τ_NN for a standalone one), ``tau_residual`` [N·m] = ``tau_hybrid − tau_rbd``.

    Inside, one Python System per step and C++ for the rest::

        Multiplexer(tau_rbd, q, qd, qdd), memory ─▶ ResidualNetworkStep ─▶ Demultiplexer ─▶ tau_hybrid
                           ▲                                      └─ next memory ─▶ ZeroOrderHold (period) ─┐
                           └────────────────────────────────────────────────────────────────────────────────┘
        Multiplexer(tau_hybrid, tau_rbd) ─▶ MatrixGain [I −I] ─▶ tau_residual

    The memory ``[started, encoder state (3n), network state]`` is the hold's discrete state (zeros at start:
    ``started`` = 0 makes the first step start the encoder at the first q and the LSTM at zero state).
    """

    def __init__(self, model: HybridModel, period_s: float | None = None):
        Diagram.__init__(self)
        self.core = core = ResidualNetworkCore(model)
        self.stepper, self.encoder, self.n, self.memory_size = core.stepper, core.encoder, core.n, core.memory_size
        n = self.n
        self.period_s = float(period_s) if period_s is not None else 1.0 / model.cfg.rate_hz
        if not self.period_s > 0:
            raise ValueError(f"ResidualNetworkSystem: period_s must be > 0 s, got {self.period_s}")
        builder = DiagramBuilder()
        step = builder.AddNamedSystem("step", ResidualNetworkStep(core))
        inputs = builder.AddNamedSystem("inputs", Multiplexer([n] * 4))
        split = builder.AddNamedSystem("split", Demultiplexer([n, self.memory_size]))
        hold = builder.AddNamedSystem("memory", ZeroOrderHold(self.period_s, self.memory_size))
        stack = builder.AddNamedSystem("stack", Multiplexer([n, n]))
        residual = builder.AddNamedSystem("residual", MatrixGain(np.hstack([np.eye(n), -np.eye(n)])))
        for i, name in enumerate(("tau_rbd", "q", "qd", "qdd")):
            builder.ExportInput(inputs.get_input_port(i), name)
        builder.Connect(inputs.get_output_port(), step.GetInputPort("inputs"))
        builder.ConnectInput("tau_rbd", stack.get_input_port(1))
        builder.Connect(step.get_output_port(), split.get_input_port())
        builder.Connect(split.get_output_port(1), hold.get_input_port())
        builder.Connect(hold.get_output_port(), step.GetInputPort("memory"))
        builder.Connect(split.get_output_port(0), stack.get_input_port(0))
        builder.Connect(stack.get_output_port(), residual.get_input_port())
        builder.ExportOutput(split.get_output_port(0), "tau_hybrid")
        builder.ExportOutput(residual.get_output_port(), "tau_residual")
        builder.BuildInto(self)
        self.set_name("residual_network")

    def initial_memory(self) -> np.ndarray:
        return self.core.initial_memory()

    def step_stacked(self, memory: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """:meth:`ResidualNetworkCore.step_stacked` — the step function of the System."""
        return self.core.step_stacked(memory, inputs)

    def step(self, memory: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau_rbd: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`step_stacked` with the inputs apart: ``(τ_hybrid [n] N·m, next memory)``."""
        out = self.step_stacked(memory, np.concatenate((tau_rbd, q, qd, qdd)))
        return out[:self.n], out[self.n:]


def AddResidualNetwork(builder: DiagramBuilder, model: HybridModel, period_s: float | None = None,
                       name: str = "residual_network") -> ResidualNetworkSystem:
    """Add a :class:`ResidualNetworkSystem` for ``model`` to ``builder`` (ports unconnected) and return it."""
    system = builder.AddSystem(ResidualNetworkSystem(model, period_s))
    system.set_name(name)
    return system
