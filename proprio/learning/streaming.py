"""The residual network's per-sample step (§4.2): the rotational-displacement encoder and the network, one sample at
a time with explicit memory — the law the residual network's System
(:class:`~proprio.systems.residual_network.ResidualNetworkSystem`, a stage of the hybrid estimation Diagram) and the
streaming estimator (:mod:`proprio.online`) call. Its output is τ_NN, the network's own output: a hybrid's τ_RBD is
added by the next stage (a Drake ``Adder`` in the Diagram). Over a whole log the same kernels run in one compiled call
(:meth:`~proprio.learning.models.StreamingStepper.run`, after :func:`~proprio.learning.features.rotational_displacement`).

The memory is ``[started, encoder state (3n), network state]``; zeros (``started`` = 0) start the encoder at the
first q and the LSTM at zero state. An LSTM reading all five feature blocks (the thesis' LSTM-2 / LSTM-2-FCL) steps
in ONE compiled kernel (:func:`_lstm_residual_step`: :func:`~proprio.learning.features.reversal_step`, then
:func:`~proprio.learning.models.lstm2_step`); other models through the same encoder kernel and
:class:`~proprio.learning.models.StreamingStepper`.
"""
from __future__ import annotations

import numba
import numpy as np

from proprio.learning.features import ReversalEncoder, reversal_step
from proprio.learning.models import HybridModel, StreamingStepper, lstm2_step

__all__ = ["ResidualNetworkCore"]


@numba.njit(cache=True)
def _lstm_residual_step(inputs, memory, memory_out, tau_out, h, r_max, cell1, cell2,
                        w_out):  # pragma: no cover (compiled)
    """One sample: the stacked inputs ``[τ_rbd; q; q̇; q̈]`` (4n) and the memory → τ_NN [n] N·m into ``tau_out`` and
    the next memory into ``memory_out`` (which must not alias ``memory``)."""
    n = tau_out.shape[0]
    q = inputs[n:2 * n]
    enc = memory_out[1:1 + 3 * n]
    if memory[0] > 0:
        enc[:] = memory[1:1 + 3 * n]
        net = memory[1 + 3 * n:]
    else:                                                     # the first sample: encoder at q, LSTM at zero state
        enc[:n] = 1.0
        enc[n:2 * n] = q
        enc[2 * n:] = q
        net = np.zeros(memory.shape[0] - 1 - 3 * n)
    x = np.empty(5 * n)
    x[:4 * n] = inputs
    reversal_step(enc[:n], enc[n:2 * n], enc[2 * n:], q, h, r_max, x[4 * n:])
    lstm2_step(cell1, cell2, w_out, x, net, memory_out[1 + 3 * n:], tau_out)
    memory_out[0] = 1.0


class ResidualNetworkCore:
    """The per-sample step of a trained MLP-7 / LSTM model (module docstring): :meth:`step_into` ``(memory, [τ_rbd;
    q; q̇; q̈]) → τ_NN, next memory``, a pure function of its arguments. τ_NN is the network's own output (a hybrid's
    residual — τ_HYB = τ_RBD + τ_NN is the next stage's sum —, a standalone model's torque). (The stepper's scratch
    makes one core unsafe to share between threads.)"""

    def __init__(self, model: HybridModel):
        if not model.cfg.streamable:
            raise ValueError(f"ResidualNetworkSystem: {model.cfg.label()} has no streaming form (Transformer); "
                             "use an MLP-7 or LSTM model")
        cfg = model.cfg
        self.stepper = StreamingStepper(model)
        self.n = n = cfg.n_joints
        self.encoder = ReversalEncoder(n, cfg.reversal_deadband_deg, cfg.r_max_deg)
        self._n_net = self.stepper.state_size
        self.memory_size = 1 + 3 * n + self._n_net
        self._fused = self.stepper.all_features
        memory = self.initial_memory()
        self.step_into(memory, np.zeros(4 * n), np.empty(n), np.empty(self.memory_size))   # compile / load

    def initial_memory(self) -> np.ndarray:
        """The memory before the first sample (``started`` = 0: the encoder starts at the first q)."""
        return np.zeros(self.memory_size)

    def step_into(self, memory: np.ndarray, inputs: np.ndarray, tau_out: np.ndarray, memory_out: np.ndarray) -> None:
        """One sample: τ_NN [n] N·m into ``tau_out`` and the next memory into ``memory_out`` (which must not alias
        ``memory``) from the memory and the stacked inputs ``[τ_rbd; q; q̇; q̈]`` (4n: N·m, rad, rad/s, rad/s²)."""
        if self._fused:
            s = self.stepper
            _lstm_residual_step(inputs, memory, memory_out, tau_out, self.encoder.h, self.encoder.r_max, s.cells[0],
                                s.cells[1], s.w_out)
            return
        n = self.n
        q = inputs[n:2 * n]
        if memory[0] > 0:
            enc, net_state = memory[1:1 + 3 * n], memory[1 + 3 * n:]
        else:
            enc, net_state = self.encoder.initial_state(q), np.zeros(self._n_net)
        r = np.empty(n)
        self.encoder.step_into(enc, q, memory_out[1:1 + 3 * n], r)
        tau_out[:], memory_out[1 + 3 * n:] = self.stepper.residual_step(inputs, net_state, r)
        memory_out[0] = 1.0
