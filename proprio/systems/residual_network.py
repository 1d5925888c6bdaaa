"""The learned residual of the hybrid model (§4.2, eq. 4.29/4.30) as a Drake System with streaming inference.

    q, qd, qdd, tau_rbd ──▶ ResidualNetworkSystem ──▶ tau_hybrid   (τ_HYB = τ_RBD + τ_NN)
                                                  └─▶ tau_residual (τ_HYB − τ_RBD)

A discrete-time system at the model's data rate (``1 / model.cfg.rate_hz``, the rate after the §4.4 decimation) in
the usual state-space form ``y_k = g(x_k, u_k)``, ``x_{k+1} = f(x_k, u_k)``:

* the state x (discrete state ``memory``) is the rotational-displacement encoder's state (direction, signed running
  extremum and reversal point per joint) and the network's recurrent state (h₁, c₁, h₂, c₂ of the LSTM; none for MLP-7);
* one step — advance the encoder with q_k, build vec(τ_RBD, q, q̇, q̈, r)_k, run the network one sample — gives both
  the output y_k and the next state; it is a cache entry computed once per sample from the inputs and the state;
* the outputs are **direct feedthrough**: at a sample time t_k they are the prediction for the inputs of t_k, with
  no sample of latency, so an observer comparing τ_HYB with the same instant's τ_J sees matched samples;
* a periodic discrete update at every t_k stores the next state (the same cache entry, so the network runs once).

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
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import DiagramBuilder, LeafSystem, ValueProducer

from proprio.learning.features import ReversalEncoder
from proprio.learning.models import HybridModel, StreamingStepper

__all__ = ["ResidualNetworkSystem", "AddResidualNetwork"]

_STARTED = np.ones(1)


class ResidualNetworkSystem(LeafSystem):
    """A trained :class:`~proprio.learning.models.HybridModel` run online, one sample per period.

    Args:
        model: a trained MLP-7 or LSTM hybrid/standalone model.
        period_s: update period [s]; default ``1 / model.cfg.rate_hz`` (the model's data rate).

    Input ports (size n each): ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²], ``tau_rbd`` [N·m] (the backbone's
    torque at the same sample). Output ports (size n, direct feedthrough): ``tau_hybrid`` [N·m] = τ_RBD + τ_NN for a
    hybrid model (τ_NN for a standalone one), ``tau_residual`` [N·m] = ``tau_hybrid − tau_rbd``.
    """

    def __init__(self, model: HybridModel, period_s: float | None = None):
        super().__init__()
        if not model.cfg.streamable:
            raise ValueError(f"ResidualNetworkSystem: {model.cfg.label()} has no streaming form (Transformer); "
                             "use an MLP-7 or LSTM model")
        self.stepper = StreamingStepper(model)
        cfg = model.cfg
        n = self.n = cfg.n_joints
        self.period_s = float(period_s) if period_s is not None else 1.0 / cfg.rate_hz
        if not self.period_s > 0:
            raise ValueError(f"ResidualNetworkSystem: period_s must be > 0 s, got {self.period_s}")
        self.encoder = ReversalEncoder(n, cfg.reversal_deadband_deg, cfg.r_max_deg)
        self._n_net = self.stepper.state_size
        self._ports = [self.DeclareVectorInputPort(name, n) for name in ("q", "qd", "qdd", "tau_rbd")]
        # memory: [started flag, encoder state (3n), network state]
        self._memory = self.DeclareDiscreteState(1 + 3 * n + self._n_net)
        # one step: (τ_hybrid [n], next memory)
        self._step = self.DeclareCacheEntry(
            "step", ValueProducer(allocate=AbstractValue.Make((np.zeros(n), np.zeros(1 + 3 * n + self._n_net))).Clone,
                                  calc=self._calc_step),
            {self.all_input_ports_ticket(), self.discrete_state_ticket(self._memory)})
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._update)
        self.DeclareVectorOutputPort("tau_hybrid", n, lambda c, o: o.SetFromVector(self._step.Eval(c)[0]))
        self.DeclareVectorOutputPort("tau_residual", n, self._calc_residual)

    def _calc_step(self, context, value) -> None:
        q, qd, qdd, tau_rbd = (p.Eval(context) for p in self._ports)
        memory = context.get_discrete_state(self._memory).get_value()
        n = self.n
        started = memory[0] > 0
        enc = memory[1:1 + 3 * n] if started else self.encoder.initial_state(q)
        r, enc = self.encoder.step_state(enc, q)
        net_state = memory[1 + 3 * n:] if started else np.zeros(self._n_net)
        tau, net_state = self.stepper.step(np.concatenate([tau_rbd, q, qd, qdd, r]), net_state)
        value.set_value((tau, np.concatenate([_STARTED, enc, net_state])))

    def _calc_residual(self, context, output) -> None:
        output.SetFromVector(self._step.Eval(context)[0] - self._ports[3].Eval(context))

    def _update(self, context, discrete_state) -> None:
        discrete_state.get_mutable_vector(self._memory).set_value(self._step.Eval(context)[1])


def AddResidualNetwork(builder: DiagramBuilder, model: HybridModel, period_s: float | None = None,
                       name: str = "residual_network") -> ResidualNetworkSystem:
    """Add a :class:`ResidualNetworkSystem` for ``model`` to ``builder`` (ports unconnected) and return it."""
    system = builder.AddSystem(ResidualNetworkSystem(model, period_s))
    system.set_name(name)
    return system
