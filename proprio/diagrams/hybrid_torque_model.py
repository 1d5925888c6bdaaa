"""The hybrid torque model τ_HYB = τ_RBD + f_NN(τ_RBD, q, q̇, q̈, r) (§4.2, eq. 4.29/4.30) as a ``TorqueModel`` of
the estimation diagram (:mod:`proprio.diagrams.estimation`), so both wrench observers run on it online.

Online, two stages on the τ_rigid of the estimator's RBD stage, as the design card draws them: the backbone adds its
friction and offsets (τ_RBD, :class:`~proprio.diagrams.torque_model.TorqueModelSystem`), the residual network runs on
vec(τ_RBD, q, q̇, q̈, r) (τ_NN, :class:`~proprio.systems.residual_network.ResidualNetworkSystem`, its memory held by a
C++ ``ZeroOrderHold``), and Drake ``Adder`` Systems sum them. The streaming estimator (:mod:`proprio.online`) chains the
same laws directly (:class:`HybridTorqueStep`).

``tau_dyn`` = τ_HYB = τ_RBD + τ_NN feeds the Jacobian observer; ``tau_int`` = τ_HYB − τ_rigid = the backbone's
friction and offsets + τ_NN feeds the momentum observer, which takes M(q) from the backbone's rigid body. The network
keeps its LSTM state and its r-encoder state from sample to sample, one step per sample at the model rate.

Offline (``tau_int``), the same model over one contiguous sequence at the model rate: the same compiled kernels over
the whole log (:func:`~proprio.learning.features.rotational_displacement`, then
:func:`~proprio.learning.evaluation.predict_streaming`, one compiled loop over the samples); the diagram matches it to
rounding (tests).

The backbone is the τ_RBD the network was trained with (the ``backbone`` spec stored in the model file): a robot's
RNEA + viscous/Coulomb friction with the law of :mod:`proprio.friction_law`
(:func:`~proprio.learning.features.rbd_provider`), or an identified
``.npz`` (its inertials, friction law and offsets, as :func:`~proprio.diagrams.estimation.load_torque_model` reads it).
:meth:`HybridTorqueModel.signals` prepares a Recording exactly as the training data were (the §4.4 pipeline of
:mod:`proprio.learning.datasets`: the one conditioning path with the training cutoff, optional τ low-pass, decimation
of the uniform grid to the model rate).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from proprio.description import RobotDescription, load_robot
from proprio.diagrams.torque_model import RigidBodyTorqueModel, load_rigid_torque_model
from proprio.dynamics import inverse_dynamics
from proprio.learning.datasets import DataConfig, condition_for_training, kept_samples
from proprio.learning.evaluation import predict_streaming
from proprio.learning.features import feature_matrix, rotational_displacement
from proprio.learning.models import HybridModel, load_model
from proprio.recording import Recording, RecordingError
from proprio.learning.streaming import ResidualNetworkCore

__all__ = ["HybridTorqueModel", "HybridTorqueStep", "load_hybrid_torque_model"]

_RATE_TOLERANCE = 0.02      # a Recording's decimated rate may differ from the model rate by 2 %


@dataclass
class HybridTorqueModel:
    """A trained hybrid network on its backbone, for :func:`~proprio.diagrams.estimation.estimate_wrench`.

    Attributes:
        backbone: the τ_RBD model the network was trained with (rigid body + friction + offsets).
        network: the trained MLP-7 / LSTM model (float64 for the offline path; Transformers have no streaming form).
        data: the data pipeline it was trained with (filters, deadband, r_max; ``decimate`` is chosen per Recording).
        name: a label for reports (e.g. the model file's name).
    """
    backbone: RigidBodyTorqueModel
    network: HybridModel
    data: DataConfig
    name: str = "hybrid"

    def __post_init__(self) -> None:
        if not self.network.cfg.streamable:
            raise ValueError(f"{self.name}: {self.network.cfg.label()} has no streaming form (Transformer); the "
                             "estimation diagram needs an MLP-7 or LSTM model")
        if self.network.cfg.n_joints != self.backbone.description.n:
            raise ValueError(f"{self.name}: the network has {self.network.cfg.n_joints} joints, the backbone "
                             f"'{self.backbone.description.name}' {self.backbone.description.n}")
        self.network = self.network.double().eval()

    @property
    def description(self) -> RobotDescription:
        return self.backbone.description

    @property
    def rate_hz(self) -> float:
        """The model's sample rate [Hz] (after the §4.4 decimation)."""
        return float(self.network.cfg.rate_hz)

    def decimation(self, rate_hz: float) -> tuple[int, bool]:
        """``(k, ok)``: the whole decimation nearest to bringing ``rate_hz`` [Hz] to the model rate, and whether
        ``rate_hz / k`` lies within 2 % of it."""
        k = max(1, int(round(rate_hz / self.rate_hz)))
        return k, abs(rate_hz / k - self.rate_hz) <= _RATE_TOLERANCE * self.rate_hz

    def log_rate(self, rate_hz: float) -> float:
        """A logging rate [Hz] this model can read: ``rate_hz`` when a whole decimation brings it to the model rate
        (:meth:`decimation`, as :meth:`signals` requires), else the rate of the recordings it was trained on (its
        rate × its config's ``decimate``, e.g. 75 Hz × 2 = 150 Hz for a 1 kHz twin that no whole step brings to
        75 Hz)."""
        return float(rate_hz) if self.decimation(rate_hz)[1] else self.rate_hz * max(1, int(self.data.decimate))

    def tau_backbone(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ_RBD ``[N,n]`` [N·m] of the backbone: the network's τ_RBD input."""
        return inverse_dynamics(self.description, q, qd, qdd) + self.backbone.tau_int(q, qd, qdd)

    def tau_int(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ_HYB − τ_rigid ``[N,n]`` [N·m] over ONE contiguous sequence at the model rate (state carried through)."""
        cfg = self.network.cfg
        rigid = inverse_dynamics(self.description, q, qd, qdd)
        r = rotational_displacement(q, cfg.reversal_deadband_deg, cfg.r_max_deg)
        backbone = rigid + self.backbone.tau_int(q, qd, qdd)                # = tau_backbone(q, qd, qdd)
        return predict_streaming(self.network, feature_matrix(backbone, q, qd, qdd, r)) - rigid

    def torque_step(self) -> "HybridTorqueStep":
        """The per-sample law (:class:`HybridTorqueStep`) that the streaming estimator runs — the laws of the
        estimation Diagram's backbone and residual-network stages and its sums, chained: τ_HYB and τ_int [N·m] from
        τ_rigid, q, q̇, q̈, the network's memory carried from sample to sample."""
        return HybridTorqueStep(self)

    def signals(self, rec: Recording) -> tuple[Recording, dict[str, np.ndarray]]:
        """``rec`` at the model rate and its signals ``t, q, qd, qdd, tau, time_step`` prepared like the training data
        (module docstring), plus ``edge_s``, the filters' edge transient [s] (``edge_cycles`` periods of the lowest
        cutoff). The conditioned grid's rate divided by a whole decimation factor must give the model rate within 2 % (e.g.
        1 kHz → every 13th sample for a 76.9 Hz model); raises :class:`RecordingError` otherwise."""
        cs, tau = condition_for_training(rec, self.data)
        k, ok = self.decimation(cs.rate_hz)
        if not ok:
            raise RecordingError(f"recording: sampled at {cs.rate_hz:.4g} Hz, which no whole decimation brings to the "
                                 f"model rate {self.rate_hz:.4g} Hz (nearest: 1 sample in {k}, "
                                 f"{cs.rate_hz / k:.4g} Hz); resample the recording")
        keep = kept_samples(cs.n_samples, cs.rate_hz, dataclasses.replace(self.data, decimate=k))
        at_rate = cs.as_recording().take(keep)
        cutoffs = [float(cs.cutoff_hz.min())] + ([self.data.tau_filter_hz] if self.data.tau_filter_hz else [])
        return at_rate, {"t": at_rate.t - at_rate.t[0], "q": cs.q[keep], "qd": cs.qd[keep], "qdd": cs.qdd[keep],
                         "tau": tau[keep], "time_step": k / cs.rate_hz, "gap": cs.gap[keep],
                         "edge_s": self.data.conditioning().edge_cycles / min(cutoffs)}


class HybridTorqueStep:
    """The per-sample torque law of a :class:`HybridTorqueModel`, the estimation Diagram's stages chained:
    :meth:`step_into` ``[τ_rigid; q; q̇; q̈], memory → [τ_HYB; τ_int], next memory`` — the backbone's law
    (:class:`~proprio.diagrams.torque_model.RigidTorqueStep`: τ_RBD = τ_rigid + its friction and offsets τ_int,RBD),
    the network's step on [τ_RBD; q; q̇; q̈] (:class:`~proprio.learning.streaming.ResidualNetworkCore`: τ_NN; its
    memory — r-encoder and LSTM state — passed in and out), then the Diagram's sums: τ_HYB = τ_RBD + τ_NN and τ_int =
    τ_int,RBD + τ_NN (a standalone network: τ_NN and τ_NN − τ_rigid)."""

    def __init__(self, model: HybridTorqueModel):
        self.n = n = model.description.n
        self.backbone = model.backbone.torque_step()
        self.core = ResidualNetworkCore(model.network)
        self.hybrid = model.network.cfg.hybrid
        self._b = self.backbone.memory_size               # memory: [backbone's (sensor terms); network's]
        self.memory_size = self._b + self.core.memory_size
        self._features = np.empty(4 * n)                  # [τ_RBD; q; q̇; q̈], the network's input
        self._backbone_out = np.empty(2 * n)              # [τ_RBD; τ_int,RBD]
        self._tau_nn = np.empty(n)

    def initial_memory(self) -> np.ndarray:
        return np.concatenate([self.backbone.initial_memory(), self.core.initial_memory()])

    def step_into(self, inputs: np.ndarray, memory: np.ndarray, out: np.ndarray, memory_out: np.ndarray) -> None:
        """``inputs = [τ_rigid; q; q̇; q̈]`` (4n: N·m, rad, rad/s, rad/s²) and ``memory`` → ``out = [τ_HYB; τ_int]``
        (2n, N·m) and the next memory into ``memory_out`` (which must not alias ``memory``)."""
        n, x, rbd, tau_nn, b = self.n, self._features, self._backbone_out, self._tau_nn, self._b
        self.backbone.step_into(inputs, memory[:b], rbd, memory_out[:b])
        x[:n] = rbd[:n]
        x[n:] = inputs[n:]
        self.core.step_into(memory[b:], x, tau_nn, memory_out[b:])
        if self.hybrid:
            np.add(rbd[:n], tau_nn, out=out[:n])
            np.add(rbd[n:], tau_nn, out=out[n:])
        else:
            out[:n] = tau_nn
            np.subtract(tau_nn, inputs[:n], out=out[n:])


def load_hybrid_torque_model(path: str | Path) -> HybridTorqueModel:
    """A :class:`HybridTorqueModel` from a model file written by ``proprio train`` (its stored backbone spec and data
    config)."""
    network, extra = load_model(path, dtype=torch.float64)
    spec = extra.get("backbone")
    if not spec:
        raise ValueError(f"{path}: the model file names no backbone; train it with `proprio train`")
    if Path(spec).suffix == ".npz":
        backbone = load_rigid_torque_model(spec)
    else:   # the training backbone rbd_provider(): RNEA + the friction law at the library's smoothing
        backbone = RigidBodyTorqueModel(load_robot(spec))
    return HybridTorqueModel(backbone, network, DataConfig.from_dict(extra.get("data")), Path(path).name)

