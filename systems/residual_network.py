"""The learned residual of the hybrid model (§4.2, eq. 4.29/4.30) as a Drake System with streaming inference.

    q, qd, qdd, tau_rbd ──▶ ResidualNetworkSystem ──▶ tau_hybrid   (τ_HYB = τ_RBD + τ_NN)
                                                  └─▶ tau_residual (τ_HYB − τ_RBD)

One periodic discrete update per sample at the model's data rate (``1 / model.cfg.rate_hz``, the rate after the
§4.4 decimation): it reads the four inputs, advances the rotational-displacement encoder (state: direction, running
extremum and reversal point per joint), builds vec(τ_RBD, q, q̇, q̈, r), advances the network one step (LSTM state
(h₁, c₁, h₂, c₂) carried in discrete state; MLP-7 is stateless) and stores the prediction in discrete state.

Both outputs are state output ports (``DeclareStateOutputPort``): no direct feedthrough, so a feedback path through
the observers or a controller never forms an algebraic loop. Latency: the update at sample time t_k stores the
prediction from the inputs sampled at t_k; the outputs show it from then on and hold it until t_{k+1} (zero-order
hold). A publish event at t_k (e.g. a ``VectorLogSink`` at the same rate) runs *before* that update — Drake publishes
at the end of the step that reaches t_k and updates at the start of the next — so it logs the prediction of
t_{k−1}: one sample of latency, exactly as an online estimator that outputs what it computed last period. A consumer that
combines tau_hybrid with same-instant measurements (a wrench observer) should therefore sample with a small offset
after t_k, or be compared against the measurements of t_{k−1}.

The step runs the model as float64 numpy (:class:`~proprio.learning.models.StreamingStepper`, the same weights and
equations as the torch model, equal to it to rounding): a torch call per sample costs ≈10× more overhead than the
arithmetic. Transformers have no streaming form and are rejected.
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from proprio.learning.features import ReversalEncoder
from proprio.learning.models import HybridModel, StreamingStepper

__all__ = ["ResidualNetworkSystem", "AddResidualNetwork"]


class ResidualNetworkSystem(LeafSystem):
    """A trained :class:`~proprio.learning.models.HybridModel` run online, one sample per period.

    Input ports (size n each): ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²], ``tau_rbd`` [N·m] (the backbone's
    torque at the same sample). Output ports (size n, state): ``tau_hybrid`` [N·m], ``tau_residual`` [N·m].
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
        self.encoder = ReversalEncoder(n, cfg.reversal_deadband_deg, cfg.r_max_deg)
        self._n_net = self.stepper.state_size
        self._ports = [self.DeclareVectorInputPort(name, n) for name in ("q", "qd", "qdd", "tau_rbd")]
        # memory: [started flag, encoder state (3n), network state]
        self._memory = self.DeclareDiscreteState(1 + 3 * n + self._n_net)
        self._hybrid = self.DeclareDiscreteState(n)
        self._residual = self.DeclareDiscreteState(n)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._update)
        self.DeclareStateOutputPort("tau_hybrid", self._hybrid)
        self.DeclareStateOutputPort("tau_residual", self._residual)

    def _update(self, context, discrete_state) -> None:
        q, qd, qdd, tau_rbd = (p.Eval(context) for p in self._ports)
        memory = context.get_discrete_state(self._memory).get_value()
        n = self.n
        enc = memory[1:1 + 3 * n] if memory[0] else self.encoder.initial_state(q)
        r, enc = self.encoder.step_state(enc, q)
        net_state = memory[1 + 3 * n:] if memory[0] else np.zeros(self._n_net)
        tau, net_state = self.stepper.step(np.concatenate([tau_rbd, q, qd, qdd, r]), net_state)
        discrete_state.get_mutable_vector(self._memory).set_value(np.concatenate([[1.0], enc, net_state]))
        discrete_state.get_mutable_vector(self._hybrid).set_value(tau)
        discrete_state.get_mutable_vector(self._residual).set_value(tau - tau_rbd)


def AddResidualNetwork(builder: DiagramBuilder, model: HybridModel, period_s: float | None = None,
                       name: str = "residual_network") -> ResidualNetworkSystem:
    """Add a :class:`ResidualNetworkSystem` for ``model`` to ``builder`` (ports unconnected) and return it."""
    system = builder.AddSystem(ResidualNetworkSystem(model, period_s))
    system.set_name(name)
    return system
