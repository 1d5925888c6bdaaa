"""The estimation diagram (DESIGN.md diagram 2): a Recording replayed through a dynamics model into both wrench
observers, logged at the data rate — the same :class:`WrenchEstimator` a live robot runs.

    TrajectorySource [q; q̇; q̈; τ_J] (conditioned, zero phase) → Demultiplexer → WrenchEstimator:
        ├─ q, q̇, q̈ → rigid_body (τ_rigid, [p; τ_g + Cᵀq̇], J(q) from one plant context)
        ├─ τ_rigid, q, q̇, q̈ → torque_model (friction, offsets: τ_RBD) ─tau_dyn─→ jacobian_observer
        │                                                              └─tau_int─→ momentum_observer
        │    a hybrid model: τ_RBD, q, q̇, q̈ → residual_network (τ_NN) → Adders tau_dyn = τ_RBD + τ_NN,
        │                                                                   tau_int = τ_int,RBD + τ_NN
        ├─ τ_J ──────────────────────────────────────────────→ both observers' tau_meas
        └─ J(q) ──────────────────────────────────────────────→ wrench (WrenchMap: one solve for both τ̂_ext)
                                                               ─estimate─→ ONE VectorLogSink

Every stage is a System with named ports (the design card's features → RBD backbone τ_RBD → residual network τ_NN →
wrench observers); C++ primitives (Multiplexer/Demultiplexer, Adder, MatrixGain, discrete LinearSystem,
ZeroOrderHold) carry everything but the Python Systems that hold real Python work (the rigid-body terms, the
backbone's friction, the network's step for a hybrid model, the wrench solve), each reading one stacked input port
and writing one output. The signals come from the one
conditioning path (:mod:`proprio.conditioning`: uniform time base, zero-phase Butterworth per joint with its cutoff from the data's
noise floor or from the config, central differences), offline, so they are computed before the replay; online, a
causal conditioning stage (:class:`~proprio.systems.causal_conditioning.CausalConditioner`) takes the raw q, τ_J
instead (``WrenchEstimator(..., conditioning=causal_conditioning(...))``; :mod:`proprio.online` chains the same laws
sample by sample from a user's loop, without a Diagram Context). ``tau_dyn`` comes from any :class:`~proprio.diagrams.torque_model.TorqueModel`: the
rigid-body model (:class:`~proprio.diagrams.torque_model.TorqueModelSystem`), or the hybrid RBD + learned residual
(:mod:`proprio.diagrams.hybrid_torque_model`), whose network then runs online in the diagram as its own stage
(:class:`~proprio.systems.residual_network.ResidualNetworkSystem`), one step per sample with its LSTM and r-encoder
state carried from sample to sample. :func:`estimate_wrench` runs it and returns an :class:`EstimationResult`.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, OutputPort
from pydrake.systems.primitives import (Adder, Demultiplexer, LogVectorOutput, MatrixGain, Multiplexer,
                                       TrajectorySource, VectorLogSink)
from pydrake.trajectories import PiecewisePolynomial

from proprio.causal_conditioning import CausalConditioning
from proprio.conditioning import ConditioningConfig, condition
from proprio.description import RobotDescription, load_robot
from proprio.dynamics import inverse_dynamics
from proprio.diagrams.torque_model import (RigidBodyTorqueModel, TorqueModel, TorqueModelSystem,
                                           load_rigid_torque_model)
from proprio.io import atomic_path
from proprio.plots.estimation import plot_force_estimates
from proprio.kinematics import chain_geometry, flange_jacobian, flange_pose, point_jacobian
from proprio.recording import Recording, RecordingError, validate_recording
from proprio.systems.causal_conditioning import CausalConditioner
from proprio.momentum import momentum_observer
from proprio.systems.momentum_observer import MomentumObserver, RigidBodyTermsSystem
from proprio.systems.observers import (JacobianWrenchObserver, WrenchMap, WrenchMapping, jacobian_wrench,
                                       wrench_from_joint_torque)

__all__ = ["TorqueModel", "RigidBodyTorqueModel", "load_torque_model", "TorqueModelSystem",
           "conditioned_signals", "check_recording_matches", "WrenchEstimator", "split_estimate",
           "build_estimation_diagram", "run_estimation_diagram", "EstimationResult", "estimate_wrench",
           "estimate_rows", "estimate_wrench_offline", "OBSERVERS", "DEFAULT_GAIN"]

OBSERVERS = ("jacobian", "momentum")
DEFAULT_GAIN = 100.0
"""Default momentum-observer gain K_O [1/s] (time constant 10 ms)."""


def load_torque_model(spec: str | Path) -> TorqueModel:
    """A model from a shipped robot name or robot YAML/URDF (its RBD + friction, e.g. ``iiwa14_identified``), an
    identified-model ``.npz`` from ``proprio identify`` (its identified inertials, friction, Coulomb law and torque
    offsets; Drake must accept the identified inertials, which an SDP model always satisfies), or a hybrid model
    ``.pt`` from ``proprio train`` (its network on the backbone it was trained with, run online by the diagram)."""
    path = Path(spec)
    if path.suffix == ".pt":
        from proprio.diagrams.hybrid_torque_model import load_hybrid_torque_model
        return load_hybrid_torque_model(path)
    return load_rigid_torque_model(path)


def check_recording_matches(rec: Recording, desc: RobotDescription) -> Recording:
    """Validate ``rec`` against the model robot ``desc``: joint count, joint limits, and — when ``meta['robot']``
    names another loadable robot — the same kinematics: flange pose and flange Jacobian (joint axes in the world)
    agree at a fixed set of configurations (link frame conventions may differ). Raises :class:`RecordingError`."""
    rec = validate_recording(rec, desc)
    name = rec.meta.get("robot")
    if not name or name == desc.name:
        return rec
    try:
        rec_robot = load_robot(name)
    except (ValueError, OSError) as exc:
        raise RecordingError(f"recording: made on robot '{name}' (meta.robot) but the model robot is '{desc.name}', "
                             f"and '{name}' is not a known description whose kinematics could be compared") from exc
    q = np.random.default_rng(0).uniform(desc.lower, desc.upper, (16, desc.n))
    same = rec_robot.n == desc.n and np.allclose(flange_pose(rec_robot, q), flange_pose(desc, q), atol=1e-6) and \
        np.allclose(flange_jacobian(rec_robot, q), flange_jacobian(desc, q), atol=1e-6)
    if not same:
        raise RecordingError(f"recording: robot '{name}' (meta.robot) does not match the model robot '{desc.name}' "
                             "(different kinematics: flange pose or joint axes differ)")
    return rec


# ---- the diagram -----------------------------------------------------------------------------------------------------

class WrenchEstimator(Diagram):
    """The online estimator, one Drake System per stage with named ports, all stepping at ``time_step``::

        [conditioner]  q, [qd], tau_meas (raw) ─▶ CausalConditioner (C++ LinearSystem) ─▶ q, qd, qdd, tau_meas
        rigid_body     q, qd, qdd ─▶ RigidBodyTermsSystem (one plant context) ─▶ tau_rigid, momentum_terms, jacobian
        torque_model   tau_rigid, q, qd, qdd ─▶ TorqueModelSystem (the rigid-body model's torque law — a hybrid
                       model's backbone: friction, offsets) ─▶ tau_dyn (τ_RBD), tau_int
        [residual_network  tau_rbd, q, qd, qdd ─▶ ResidualNetworkSystem (a hybrid model's network, its memory in a
                       C++ ZeroOrderHold) ─▶ tau_nn; C++ Adders tau_dyn = τ_RBD + τ_NN, tau_int = τ_int,RBD + τ_NN]
        jacobian_observer  tau_dyn, tau_meas ─▶ (C++ MatrixGain [I −I]) ─▶ tau_ext = τ_dyn − τ_J
        momentum_observer  momentum_terms, tau_meas, tau_int ─▶ (C++ discrete LinearSystem) ─▶ tau_ext = r
        wrench             jacobian, tau_ext_jacobian, tau_ext_momentum ─▶ WrenchMap (one solve for both) ─▶ estimate

    Each Python System is a thin wrapper of a law written once below the Systems (:mod:`proprio.rigid_body_terms`,
    the rigid-body model's ``torque_step``, :class:`~proprio.learning.streaming.ResidualNetworkCore`,
    :mod:`proprio.wrench_solve`); the C++ ``LinearSystem`` stages step the matrices of
    :func:`~proprio.causal_conditioning.causal_conditioning` and :func:`~proprio.momentum.momentum_filter`.
    :class:`proprio.online.OnlineEstimator` chains the same laws directly, sample by sample.

    Input ports: without ``conditioning`` the conditioned ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²],
    ``tau_meas`` [N·m] (e.g. a replay of :func:`proprio.conditioning.condition`); with a
    :class:`~proprio.causal_conditioning.CausalConditioning` the raw ``q``, (``qd`` for ``velocity="measured"``) and
    ``tau_meas`` of the robot. Output ports: ``estimate`` = ``[f̂_jacobian (6), f̂_momentum (6), manipulability,
    unreliable, τ̂_ext,jacobian (n), τ̂_ext,momentum (n)]`` (:func:`split_estimate`); ``wrench_jacobian``,
    ``wrench_momentum`` (6 each) [fx, fy, fz, mx, my, mz] on the robot at the contact point (flange origin by
    default), world frame, N and N·m; ``manipulability``, ``unreliable`` (1 each).

    Call :meth:`set_initial_state` once the first sample is on the inputs: it starts the conditioner in that
    sample's steady state and the momentum observer at r = 0 (:class:`MomentumObserver`). The replay
    (:func:`run_estimation_diagram`) advances it with a Simulator and :func:`estimate_rows` evaluates the same laws
    vectorised.
    """

    def __init__(self, model: TorqueModel, time_step: float, gain: float | np.ndarray = DEFAULT_GAIN,
                 mapping: WrenchMapping = WrenchMapping(), conditioning: CausalConditioning | None = None):
        Diagram.__init__(self)
        desc = model.description
        n = desc.n
        if conditioning is not None and abs(conditioning.time_step - time_step) > 1e-9 * time_step:
            raise ValueError(f"WrenchEstimator: the conditioning is designed for {conditioning.rate_hz:g} Hz, the "
                             f"estimator steps every {time_step:g} s")
        self.model, self.time_step, self.gain, self.mapping = model, float(time_step), gain, mapping
        builder = DiagramBuilder()
        self.rigid_body = builder.AddNamedSystem("rigid_body", RigidBodyTermsSystem(desc, mapping.contact_point))
        network = getattr(model, "network", None)           # a hybrid model: its backbone, then its network
        self.torque_model = builder.AddNamedSystem("torque_model", TorqueModelSystem(
            model if network is None else model.backbone, time_step))
        self.residual = None
        if network is not None:
            from proprio.systems.residual_network import ResidualNetworkSystem     # torch only for a hybrid model
            self.residual = builder.AddNamedSystem("residual_network", ResidualNetworkSystem(network, time_step))
        self.jacobian = builder.AddNamedSystem("jacobian_observer", JacobianWrenchObserver(n))
        self.momentum = builder.AddNamedSystem("momentum_observer", MomentumObserver(desc, time_step, gain))
        self.wrench = builder.AddNamedSystem("wrench", WrenchMap(desc, mapping, OBSERVERS, jacobian_input=True))
        self.conditioner = None
        signal: dict = {name: None for name in ("q", "qd", "qdd", "tau_meas")}
        if conditioning is not None:
            self.conditioner = builder.AddNamedSystem("conditioner", CausalConditioner(conditioning))
            for i in range(self.conditioner.num_input_ports()):
                port = self.conditioner.get_input_port(i)
                builder.ExportInput(port, port.get_name())
            signal = {name: self.conditioner.GetOutputPort(name) for name in signal}

        def connect(name: str, dest) -> None:          # a conditioner's output, else the Diagram's input port
            if signal[name] is not None:
                builder.Connect(signal[name], dest)
            elif name in exported:
                builder.ConnectInput(name, dest)
            else:
                builder.ExportInput(dest, name)
                exported.add(name)

        exported: set[str] = set()
        stages = [self.rigid_body, self.torque_model] + ([self.residual] if self.residual is not None else [])
        for name in ("q", "qd", "qdd"):
            for stage in stages:
                connect(name, stage.GetInputPort(name))
        connect("tau_meas", self.jacobian.GetInputPort("tau_meas"))
        connect("tau_meas", self.momentum.GetInputPort("tau_meas"))
        builder.Connect(self.rigid_body.GetOutputPort("tau_rigid"), self.torque_model.GetInputPort("tau_rigid"))
        tau_dyn, tau_int = self.torque_model.GetOutputPort("tau_dyn"), self.torque_model.GetOutputPort("tau_int")
        if self.residual is not None:
            tau_dyn, tau_int = self._add_residual(builder, n, tau_dyn, tau_int)
        builder.Connect(tau_dyn, self.jacobian.GetInputPort("tau_dyn"))
        builder.Connect(self.rigid_body.GetOutputPort("momentum_terms"), self.momentum.GetInputPort("momentum_terms"))
        builder.Connect(tau_int, self.momentum.GetInputPort("tau_int"))
        builder.Connect(self.rigid_body.GetOutputPort("jacobian"), self.wrench.GetInputPort("jacobian"))
        builder.Connect(self.jacobian.GetOutputPort("tau_ext"), self.wrench.GetInputPort("tau_ext_jacobian"))
        builder.Connect(self.momentum.GetOutputPort("tau_ext"), self.wrench.GetInputPort("tau_ext_momentum"))
        for name in ("estimate", "wrench_jacobian", "wrench_momentum", "manipulability", "unreliable"):
            builder.ExportOutput(self.wrench.GetOutputPort(name), name)
        builder.BuildInto(self)
        self.set_name("wrench_estimator")

    def _add_residual(self, builder: DiagramBuilder, n: int, tau_rbd: OutputPort, tau_int_rbd: OutputPort
                      ) -> tuple[OutputPort, OutputPort]:
        """Feed the backbone's τ_RBD to the residual network and return the ports of τ_dyn and τ_int: for a hybrid
        network two Drake ``Adder`` Systems, τ_HYB = τ_RBD + τ_NN and τ_int = τ_int,RBD + τ_NN; for a standalone one τ_NN and
        τ_NN − τ_rigid (``Multiplexer`` → ``MatrixGain [I −I]``)."""
        residual = self.residual
        builder.Connect(tau_rbd, residual.GetInputPort("tau_rbd"))
        tau_nn = residual.GetOutputPort("tau_nn")
        if self.model.network.cfg.hybrid:
            sums = [builder.AddNamedSystem(name, Adder(2, n)) for name in ("tau_dyn", "tau_int")]
            for adder, port in zip(sums, (tau_rbd, tau_int_rbd)):
                builder.Connect(port, adder.get_input_port(0))
                builder.Connect(tau_nn, adder.get_input_port(1))
            return sums[0].get_output_port(), sums[1].get_output_port()
        stack = builder.AddNamedSystem("tau_int_stack", Multiplexer([n, n]))
        diff = builder.AddNamedSystem("tau_int", MatrixGain(np.hstack([np.eye(n), -np.eye(n)])))
        builder.Connect(tau_nn, stack.get_input_port(0))
        builder.Connect(self.rigid_body.GetOutputPort("tau_rigid"), stack.get_input_port(1))
        builder.Connect(stack.get_output_port(), diff.get_input_port())
        return tau_nn, diff.get_output_port()

    def set_initial_state(self, context: Context) -> None:
        """Start the stages' states from the sample the inputs show now (this System's context, e.g.
        ``GetMyMutableContextFromRoot``): the conditioner in its steady state, the momentum observer at r = 0."""
        if self.conditioner is not None:
            self.conditioner.set_initial_state(self.GetMutableSubsystemContext(self.conditioner, context))
        self.momentum.set_initial_state(self.GetMutableSubsystemContext(self.momentum, context))


def split_estimate(estimate: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """``estimate [..., 14 + 2n]`` (the :class:`WrenchEstimator` port) → ``jacobian.wrench``, ``momentum.wrench``
    ``[..., 6]``, ``manipulability``, ``unreliable`` ``[...]``, ``jacobian.tau_ext``, ``momentum.tau_ext`` ``[..., n]``."""
    return {"jacobian.wrench": estimate[..., 0:6], "momentum.wrench": estimate[..., 6:12],
            "manipulability": estimate[..., 12], "unreliable": estimate[..., 13],
            "jacobian.tau_ext": estimate[..., 14:14 + n], "momentum.tau_ext": estimate[..., 14 + n:14 + 2 * n]}


def build_estimation_diagram(model: TorqueModel, signals: dict[str, np.ndarray],
                             gain: float | np.ndarray = DEFAULT_GAIN,
                             mapping: WrenchMapping = WrenchMapping(),
                             conditioning: CausalConditioning | None = None
                             ) -> tuple[Diagram, WrenchEstimator, VectorLogSink]:
    """The replay diagram: ``signals`` (``t``, ``q``, ``tau``, and ``qd``, ``qdd`` when no causal ``conditioning``
    is given — see :func:`conditioned_signals`; with one, the raw ``q``, ``tau`` (and ``qd`` for a measured-velocity
    design) of the robot) replayed by a ``TrajectorySource`` (first-order hold) into a :class:`WrenchEstimator`, whose
    ``estimate`` port ONE logger samples every ``signals['time_step']`` from t = 0. Returns the diagram, the
    estimator and the logger; :func:`run_estimation_diagram` runs it."""
    n = model.description.n
    h = signals["time_step"]
    if conditioning is None:
        channels = ("q", "qd", "qdd", "tau")
    else:
        channels = ("q", "qd", "tau") if conditioning.velocity == "measured" else ("q", "tau")
    builder = DiagramBuilder()
    stacked = np.hstack([signals[k] for k in channels]).T
    source = builder.AddNamedSystem("recording", TrajectorySource(
        PiecewisePolynomial.FirstOrderHold(signals["t"], stacked)))
    demux = builder.AddNamedSystem("signals", Demultiplexer([n] * len(channels)))
    builder.Connect(source.get_output_port(), demux.get_input_port())
    estimator = builder.AddNamedSystem("estimator", WrenchEstimator(model, h, gain, mapping, conditioning))
    for i, name in enumerate(channels):
        builder.Connect(demux.get_output_port(i), estimator.GetInputPort("tau_meas" if name == "tau" else name))
    logger = LogVectorOutput(estimator.GetOutputPort("estimate"), builder, publish_period=h)
    logger.set_name("estimate_log")
    return builder.Build(), estimator, logger


def run_estimation_diagram(diagram: Diagram, estimator: WrenchEstimator, logger: VectorLogSink, t_end: float,
                           time_step: float) -> np.ndarray:
    """Simulate the replay diagram to ``t_end`` [s] (stages started from the first sample) and return the logged
    ``estimate`` rows ``[N, 14 + 2n]``, one per sample."""
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    estimator.set_initial_state(estimator.GetMyMutableContextFromRoot(context))
    simulator.Initialize()
    simulator.AdvanceTo(float(t_end) + 0.5 * time_step)
    return logger.FindLog(simulator.get_context()).data().T


@dataclass
class EstimationResult:
    """Wrench estimates over a Recording's samples (world frame at the flange, ``[fx, fy, fz, mx, my, mz]``).

    ``q [N,n]`` the filtered joint positions the observers used; ``wrench[obs]`` ``[N,6]`` and ``tau_ext[obs]``
    ``[N,n]`` per observer (``"jacobian"``, ``"momentum"``);
    ``manipulability [N]`` and ``unreliable [N]`` (bool) of the Jacobian mapping; ``f_true`` the Recording's true
    wrench or None. :meth:`force_stats` skips ``skip_start_s`` at the start (the momentum observer's transient 5/K_O
    and the filters' edge) and ``skip_end_s`` at the end (the zero-phase filters' edge).

    ``gap [N]`` (bool): grid samples inside a gap of the log (a dropout longer than the conditioning's ``max_gap_s``,
    :func:`proprio.time_base.uniform_time_base`). Nothing was measured there, so every per-sample value at those
    samples (``q``, wrenches, ``tau_ext``, ``manipulability``, ``f_true``) is NaN — never an estimate from
    interpolated signals — and :meth:`valid` also drops the transients around each gap, as at the ends.
    """
    t: np.ndarray
    q: np.ndarray
    wrench: dict[str, np.ndarray]
    tau_ext: dict[str, np.ndarray]
    manipulability: np.ndarray
    unreliable: np.ndarray
    f_true: np.ndarray | None
    skip_start_s: float
    skip_end_s: float
    meta: dict[str, Any] = field(default_factory=dict)
    gap: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.gap = np.zeros(self.t.shape, dtype=bool) if self.gap is None else np.asarray(self.gap, dtype=bool)
        if self.gap.shape != self.t.shape:
            raise ValueError(f"EstimationResult: 'gap' has shape {list(self.gap.shape)}, expected [{self.t.size}]")
        if self.gap.any():                       # nothing was measured there: no value (module rule, no invention)
            blank = lambda a: None if a is None else np.where(  # noqa: E731
                self.gap.reshape((-1,) + (1,) * (np.ndim(a) - 1)), np.nan, a)
            self.q, self.manipulability, self.f_true = blank(self.q), blank(self.manipulability), blank(self.f_true)
            self.wrench = {k: blank(v) for k, v in self.wrench.items()}
            self.tau_ext = {k: blank(v) for k, v in self.tau_ext.items()}
            self.unreliable = np.asarray(self.unreliable, dtype=bool) & ~self.gap

    def valid(self) -> np.ndarray:
        """Samples used for statistics: measured (not in a gap of the log), away from the start-up and edge
        transients — at both ends and on both sides of every gap — and not flagged unreliable."""
        t = self.t
        ok = (t >= t[0] + self.skip_start_s) & (t <= t[-1] - self.skip_end_s) & ~self.unreliable & ~self.gap
        if self.gap.any():
            last_gap = np.maximum.accumulate(np.where(self.gap, t, -np.inf))          # latest gap sample ≤ t
            next_gap = np.minimum.accumulate(np.where(self.gap, t, np.inf)[::-1])[::-1]  # earliest gap sample ≥ t
            ok &= (t - last_gap >= self.skip_start_s) & (next_gap - t >= self.skip_end_s)
        return ok

    def force_rms(self, observer: str) -> np.ndarray:
        """RMS ``[3]`` [N] of the estimated force f̂ per axis over the :meth:`valid` samples (NaN where none is)."""
        mask = self.valid()
        if not mask.any():
            return np.full(3, np.nan)
        return np.sqrt(np.mean(self.wrench[observer][mask, :3] ** 2, axis=0))

    def force_stats(self, observer: str) -> tuple[np.ndarray, np.ndarray]:
        """RMSE ``[3]`` and standard deviation ``[3]`` [N] of the force error f̂ − f_true per axis (Table 5.4)."""
        if self.f_true is None:
            raise ValueError("force_stats: the recording has no true wrench 'f_ext'")
        mask = self.valid()
        if not mask.any():
            raise ValueError("force_stats: no valid samples (all within the start-up transient, a gap of the log or "
                             "unreliable)")
        err = self.wrench[observer][mask, :3] - self.f_true[mask, :3]
        return np.sqrt(np.mean(err ** 2, axis=0)), np.std(err, axis=0)

    def arrays(self) -> dict[str, np.ndarray]:
        """Flat ``name → array`` view for npz export (read back by :meth:`load`)."""
        out = {"t": self.t, "q": self.q, "manipulability": self.manipulability,
               "unreliable": self.unreliable.astype(float), "skip_s": np.array([self.skip_start_s, self.skip_end_s]),
               "gap": self.gap, "valid": self.valid()}
        for obs in OBSERVERS:
            out[f"wrench_{obs}"] = self.wrench[obs]
            out[f"tau_ext_{obs}"] = self.tau_ext[obs]
        if self.f_true is not None:
            out["f_true"] = self.f_true
        return out

    def save(self, out_dir: str | Path, stem: str = "estimates") -> list[Path]:
        """Write ``<stem>.npz`` (all arrays + ``meta`` JSON) and ``<stem>.csv`` (t, wrenches, flags) atomically; rows
        inside a gap of the log hold NaN, and the ``valid`` channel (1/0) marks the samples statistics use."""
        out_dir = Path(out_dir)
        npz, csv = out_dir / f"{stem}.npz", out_dir / f"{stem}.csv"
        with atomic_path(npz) as tmp:
            np.savez_compressed(tmp, **self.arrays(), meta=np.array(json.dumps(self.meta, sort_keys=True)))
        axes = ("fx", "fy", "fz", "mx", "my", "mz")
        columns = [("t", self.t)]
        sources = [(obs, self.wrench[obs]) for obs in OBSERVERS] + ([("true", self.f_true)] if self.f_true is not
                                                                    None else [])
        columns += [(f"{a}_{name}", w[:, i]) for name, w in sources for i, a in enumerate(axes)]
        columns += [("manipulability", self.manipulability), ("unreliable", self.unreliable.astype(float)),
                    ("valid", self.valid().astype(float))]
        table = np.column_stack([c for _, c in columns])
        with atomic_path(csv) as tmp:
            np.savetxt(tmp, table, delimiter=",", header=",".join(n for n, _ in columns), comments="", fmt="%.9g")
        return [npz, csv]

    @classmethod
    def load(cls, path: str | Path) -> "EstimationResult":
        """Read an ``estimates.npz`` written by :meth:`save` (``allow_pickle=False``); raises :class:`RecordingError`
        naming a missing key."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise RecordingError(f"{path}: not a readable estimates .npz ({exc})") from None
        need = ["t", "q", "manipulability", "unreliable", "skip_s", "meta"] + [
            f"{a}_{o}" for o in OBSERVERS for a in ("wrench", "tau_ext")]
        missing = [k for k in need if k not in data]
        if missing:
            raise RecordingError(f"{path}: estimates file lacks {', '.join(repr(k) for k in missing)} (written by an "
                                 "older `proprio estimate`? run it again)")
        return cls(t=data["t"], q=data["q"], wrench={o: data[f"wrench_{o}"] for o in OBSERVERS},
                   tau_ext={o: data[f"tau_ext_{o}"] for o in OBSERVERS}, manipulability=data["manipulability"],
                   unreliable=data["unreliable"] > 0.5, f_true=data.get("f_true"),
                   skip_start_s=float(data["skip_s"][0]), skip_end_s=float(data["skip_s"][1]),
                   meta=json.loads(str(data["meta"])), gap=data.get("gap"))

    def plot(self, path: str | Path, title: str = "") -> Path:
        """PNG of f̂ (both observers) against the true force per axis over time, flagged samples shaded."""
        return plot_force_estimates(
            path, self.t, {o: self.wrench[o] for o in OBSERVERS}, self.f_true, self.gap, self.unreliable,
            self.skip_start_s, self.skip_end_s,
            title or f"external force at the flange (world frame), model {self.meta.get('model', '?')}")


def conditioned_signals(rec: Recording, conditioning: ConditioningConfig = ConditioningConfig()
                        ) -> tuple[Recording, dict[str, np.ndarray], float]:
    """The Recording on its uniform grid, the replayed signals ``t, q, qd, qdd, tau`` (+ ``time_step``, and ``gap``:
    the grid samples inside gaps of the log) of the one conditioning path (:func:`proprio.conditioning.condition`)
    and the filters' edge transient [s]."""
    cs = condition(rec, conditioning)
    sig = {"t": cs.t, "q": cs.q, "qd": cs.qd, "qdd": cs.qdd, "tau": cs.tau, "time_step": 1.0 / cs.rate_hz,
           "gap": cs.gap}
    return cs.as_recording(), sig, conditioning.edge_cycles / float(cs.cutoff_hz.min())


def _prepare(model: TorqueModel | RobotDescription, rec: Recording, conditioning: ConditioningConfig
             ) -> tuple[TorqueModel, Recording, dict[str, np.ndarray], float]:
    """The model, the Recording at the rate the diagram runs, its signals and the filters' edge transient [s]."""
    if isinstance(model, RobotDescription):
        model = RigidBodyTorqueModel(model)
    rec = check_recording_matches(rec, model.description)
    if hasattr(model, "signals"):             # its own pipeline: decimation to its rate, as in training
        rec, sig = model.signals(rec)
        return model, rec, sig, sig.pop("edge_s")
    return (model, *conditioned_signals(rec, conditioning))


def _skips(gain: float | np.ndarray, edge_s: float) -> dict[str, float]:
    return {"skip_start_s": max(float(5.0 / np.min(gain)), edge_s), "skip_end_s": edge_s}


def _meta(model: TorqueModel, rec: Recording, gain: float | np.ndarray, mapping: WrenchMapping,
          conditioning: ConditioningConfig, engine: str) -> dict[str, Any]:
    return {"model": getattr(model, "name", model.description.name), "recording": dict(rec.meta),
            "gain": np.asarray(gain).tolist(), "mapping": asdict(mapping), "conditioning": rec.meta.get("conditioned", asdict(conditioning)),
            "engine": engine}


def estimate_wrench(model: TorqueModel | RobotDescription, rec: Recording, gain: float | np.ndarray = DEFAULT_GAIN,
                    mapping: WrenchMapping = WrenchMapping(),
                    conditioning: ConditioningConfig = ConditioningConfig()
                    ) -> EstimationResult:
    """Run the estimation diagram over ``rec`` with ``model`` (a :class:`TorqueModel` or a description, taken as
    its rigid-body model + friction). ``gain`` is the momentum observer's K_O [1/s] (scalar or per joint).

    The Recording goes through the one conditioning path (:func:`proprio.conditioning.condition`: a jittered log is
    resampled onto a uniform grid, the result's ``t`` is that grid). A hybrid model (``model.signals``) replaces
    ``conditioning`` by its own training-time preprocessing and runs at its own rate: the result then holds the
    Recording's samples kept at that rate. Raises
    :class:`RecordingError` when the Recording does not match the model robot or is too short for the filters."""
    model, rec, sig, edge_s = _prepare(model, rec, conditioning)
    diagram, estimator, logger = build_estimation_diagram(model, sig, gain, mapping)
    rows = run_estimation_diagram(diagram, estimator, logger, sig["t"][-1], sig["time_step"])[:rec.n_samples]
    return _result(model, rec, sig, rows, edge_s, gain, mapping, conditioning, "diagram")


def _result(model: TorqueModel, rec: Recording, sig: dict[str, np.ndarray], rows: np.ndarray, edge_s: float,
            gain: float | np.ndarray, mapping: WrenchMapping, conditioning: ConditioningConfig, engine: str
            ) -> EstimationResult:
    """The :class:`EstimationResult` of the ``estimate`` rows over the Recording's samples."""
    logs = split_estimate(rows, model.description.n)
    return EstimationResult(
        t=rec.t.copy(), q=sig["q"], wrench={o: logs[f"{o}.wrench"] for o in OBSERVERS},
        tau_ext={o: logs[f"{o}.tau_ext"] for o in OBSERVERS},
        manipulability=logs["manipulability"], unreliable=logs["unreliable"] > 0.5,
        f_true=None if rec.f_ext is None else rec.f_ext.copy(), **_skips(gain, edge_s),
        meta=_meta(model, rec, gain, mapping, conditioning, engine), gap=sig.get("gap"))


def estimate_rows(model: TorqueModel, signals: dict[str, np.ndarray], gain: float | np.ndarray = DEFAULT_GAIN,
                  mapping: WrenchMapping = WrenchMapping()) -> np.ndarray:
    """The :class:`WrenchEstimator`'s ``estimate`` rows ``[N, 14 + 2n]`` (:func:`split_estimate`) for the conditioned
    ``signals`` (``q, qd, qdd, tau`` ``[N,n]`` and ``time_step``: what the Diagram's torque model and observers see,
    from a zero-phase or a causal conditioning), from the vectorised form of the same laws instead of stepping the
    Diagram: the model's batch ``tau_int``, :func:`jacobian_wrench` and :func:`momentum_observer` (the recursion of
    the momentum System's ``LinearSystem``, :func:`~proprio.momentum.momentum_filter`). As in the
    Diagram (Drake discrete semantics) the momentum estimate at sample k is r_{k−1} (0 at the first sample)."""
    desc = model.description
    q, qd, qdd, tau = signals["q"], signals["qd"], signals["qdd"], signals["tau"]
    tau_int = model.tau_int(q, qd, qdd)
    tau_dyn = inverse_dynamics(desc, q, qd, qdd) + tau_int
    geo = chain_geometry(desc)
    w_jac, manip, flag = jacobian_wrench(geo, q, tau, tau_dyn, mapping)
    r = momentum_observer(desc, signals["time_step"], q, qd, tau, tau_int, gain)
    r = np.vstack([np.zeros((1, desc.n)), r[:-1]])                  # the System's output: r_{k−1}
    w_mom, _, _ = wrench_from_joint_torque(point_jacobian(geo, q, np.asarray(mapping.contact_point)), r, mapping)
    return np.hstack([w_jac, w_mom, manip[:, None], flag[:, None].astype(float), tau_dyn - tau, r])


def estimate_wrench_offline(model: TorqueModel | RobotDescription, rec: Recording,
                            gain: float | np.ndarray = DEFAULT_GAIN,
                            mapping: WrenchMapping = WrenchMapping(),
                            conditioning: ConditioningConfig = ConditioningConfig()
                            ) -> EstimationResult:
    """The same estimates as :func:`estimate_wrench`, sample for sample, from the vectorised form of the same laws
    (:func:`estimate_rows`) instead of stepping the diagram. Tests: equal to the diagram's to 1e-9."""
    model, rec, sig, edge_s = _prepare(model, rec, conditioning)
    return _result(model, rec, sig, estimate_rows(model, sig, gain, mapping), edge_s, gain, mapping, conditioning,
                   "offline")
