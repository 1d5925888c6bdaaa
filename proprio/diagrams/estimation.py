"""The estimation diagram (DESIGN.md diagram 2): a Recording replayed through a dynamics model into both wrench
observers, logged at the data rate.

    TrajectorySource [q; q̇; q̈; τ_J] (conditioned, zero phase) → Demultiplexer
        ├─ q, q̇, q̈ → TorqueModelSystem ──tau_dyn──→ JacobianWrenchObserver ──→ VectorLogSink (f̂, τ̂_ext, flags)
        │                               └─tau_int──→ MomentumObserver ───────→ VectorLogSink (f̂, τ̂_ext)
        └─ τ_J ───────────────────────────────────→ both observers' tau_meas

The signals come from the one conditioning path (:mod:`proprio.conditioning`: uniform time base, zero-phase
Butterworth per joint with its cutoff from the data's noise floor or from the config, central differences), offline,
so they are computed before the replay; the observers themselves are causal Systems that would run unchanged on live sensor ports. ``tau_dyn`` comes from any
:class:`TorqueModel`: the rigid-body model (:class:`TorqueModelSystem`), or the hybrid RBD + learned residual
(:mod:`proprio.diagrams.hybrid_torque_model`), whose network then runs online in the diagram, one step per sample with
its LSTM and r-encoder state carried from sample to sample. :func:`estimate_wrench` runs it and returns an
:class:`EstimationResult`.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem, System, ValueProducer
from pydrake.systems.primitives import Demultiplexer, LogVectorOutput, TrajectorySource, VectorLogSink
from pydrake.trajectories import PiecewisePolynomial

from proprio.conditioning import ConditioningConfig, condition
from proprio.description import RobotDescription, load_robot
from proprio.dynamics import inverse_dynamics
from proprio.io import atomic_path, save_figure
from proprio.kinematics import chain_geometry, flange_jacobian, flange_pose, point_jacobian
from proprio.plant import DrakeRobot
from proprio.recording import Recording, RecordingError, validate_recording
from proprio.systems.observers import (JacobianWrenchObserver, MomentumObserver, WrenchMapping, jacobian_wrench,
                                       momentum_observer, wrench_from_joint_torque)

__all__ = ["TorqueModel", "RigidBodyTorqueModel", "load_torque_model", "TorqueModelSystem", "conditioned_signals",
           "check_recording_matches", "AddWrenchObservers",
           "build_estimation_diagram", "EstimationResult", "estimate_wrench", "estimate_wrench_offline", "OBSERVERS",
           "DEFAULT_GAIN"]

OBSERVERS = ("jacobian", "momentum")
DEFAULT_GAIN = 100.0
"""Default momentum-observer gain K_O [1/s] (time constant 10 ms)."""


class TorqueModel(Protocol):
    """A joint-torque model τ_dyn = τ_rbd + τ_int (eq. 3.9), vectorised over samples ``[N,n]``.

    ``description`` gives the kinematics and the rigid-body inertials: τ_rbd is its inverse dynamics (Drake's
    ``CalcInverseDynamics`` per step in the diagram, :func:`proprio.dynamics.inverse_dynamics` offline) and the
    momentum observer takes M(q) from it. ``tau_int`` is everything the model adds to the rigid body (link friction,
    a learned residual).

    A model with memory (the hybrid model, :mod:`proprio.diagrams.hybrid_torque_model`) also provides
    ``make_system(time_step) -> System`` (the ports of :class:`TorqueModelSystem`, run online by the diagram instead of
    it) and ``signals(rec) -> (Recording, signals)`` (its own preprocessing at its own rate, instead of
    :func:`conditioned_signals`; ``signals["edge_s"]`` is its filters' edge transient [s]) and a ``name``."""
    description: RobotDescription

    def tau_int(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class RigidBodyTorqueModel:
    """The RBD model of a description plus its link-side viscous + Coulomb friction, if it has any, and constant
    torque offsets: ``τ_int = F_v q̇ + F_c sgn(q̇) + τ_offset`` [N·m] with ``sgn = tanh(q̇ / coulomb_velocity)``
    (``np.sign`` when 0). The default 0.02 rad/s smooths the sign over the band where filtered velocities are
    unreliable."""
    description: RobotDescription
    coulomb_velocity: float = 0.02
    offset: tuple[float, ...] | None = None

    def tau_int(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        d = self.description
        qd = np.asarray(qd, dtype=float)
        tau = np.zeros_like(qd) if self.offset is None else np.broadcast_to(self.offset, qd.shape).copy()
        if d.has_friction:
            sgn = np.sign(qd) if self.coulomb_velocity == 0 else np.tanh(qd / self.coulomb_velocity)
            tau += np.asarray(d.friction_viscous) * qd + np.asarray(d.friction_coulomb) * sgn
        return tau


def load_torque_model(spec: str | Path) -> TorqueModel:
    """A model from a shipped robot name or robot YAML/URDF (its RBD + friction, e.g. ``iiwa14_identified``), an
    identified-model ``.npz`` from ``proprio identify`` (its identified inertials, friction, Coulomb law and torque
    offsets; Drake must accept the identified inertials, which an SDP model always satisfies), or a hybrid model
    ``.pt`` from ``proprio train`` (its network on the backbone it was trained with, run online by the diagram)."""
    path = Path(spec)
    if path.suffix == ".pt":
        from proprio.diagrams.hybrid_torque_model import load_hybrid_torque_model
        return load_hybrid_torque_model(path)
    if path.suffix == ".npz":
        from proprio.identification.model_io import load_model
        ident = load_model(path)
        model = RigidBodyTorqueModel(ident.description_identified(), ident.coulomb_velocity_scale,
                                     tuple(float(x) for x in ident.offsets))
        try:
            DrakeRobot(model.description)
        except (RuntimeError, ValueError) as exc:
            raise ValueError(f"{path}: Drake cannot build a plant from the identified inertials "
                             f"({str(exc).splitlines()[0]}); identify with --method sdp for a physically consistent "
                             "model") from None
        return model
    return RigidBodyTorqueModel(load_robot(spec))


class TorqueModelSystem(LeafSystem):
    """A :class:`TorqueModel` as a System (τ_rbd from Drake's ``CalcInverseDynamics``). Inputs ``q``, ``qd``,
    ``qdd`` (n each, rad, rad/s, rad/s²); outputs ``tau_dyn`` = τ_rbd + τ_int and ``tau_int`` (n each, N·m), both
    computed once per context."""

    def __init__(self, model: TorqueModel):
        LeafSystem.__init__(self)
        self._model = model
        self._arm = DrakeRobot(model.description)
        n = model.description.n
        for name in ("q", "qd", "qdd"):
            self.DeclareVectorInputPort(name, n)
        cache = self.DeclareCacheEntry(
            "torques", ValueProducer(allocate=AbstractValue.Make(np.zeros(2 * n)).Clone, calc=self._calc),
            {self.all_input_ports_ticket()})
        self.DeclareVectorOutputPort("tau_dyn", n, lambda c, o: o.SetFromVector(cache.Eval(c)[:n]))
        self.DeclareVectorOutputPort("tau_int", n, lambda c, o: o.SetFromVector(cache.Eval(c)[n:]))

    def _calc(self, context, value) -> None:
        q, qd, qdd = (self.get_input_port(i).Eval(context) for i in range(3))
        tau_int = self._model.tau_int(q[None, :], qd[None, :], qdd[None, :])[0]
        value.set_value(np.concatenate([self._arm.inverse_dynamics(q, qd, qdd) + tau_int, tau_int]))


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

def AddWrenchObservers(builder: DiagramBuilder, model: TorqueModel, time_step: float,
                       gain: float | np.ndarray = DEFAULT_GAIN,
                       mapping: WrenchMapping = WrenchMapping()
                       ) -> tuple[System, JacobianWrenchObserver, MomentumObserver]:
    """Add the torque model (a :class:`TorqueModelSystem`, or the model's own ``make_system(time_step)``) and both
    observers to ``builder`` and wire the model into them. The caller connects the ``q``, ``qd``, ``qdd`` inputs of
    the model and ``q``/``qd``/``tau_meas`` of the observers."""
    desc = model.description
    system = model.make_system(time_step) if hasattr(model, "make_system") else TorqueModelSystem(model)
    torque_model = builder.AddNamedSystem("torque_model", system)
    jac = builder.AddNamedSystem("jacobian_observer", JacobianWrenchObserver(desc, mapping))
    mom = builder.AddNamedSystem("momentum_observer", MomentumObserver(desc, time_step, gain, mapping))
    builder.Connect(torque_model.GetOutputPort("tau_dyn"), jac.GetInputPort("tau_dyn"))
    builder.Connect(torque_model.GetOutputPort("tau_int"), mom.GetInputPort("tau_int"))
    return torque_model, jac, mom


_LOGGED = {"jacobian": ("wrench", "tau_ext", "manipulability", "unreliable"), "momentum": ("wrench", "tau_ext")}


def build_estimation_diagram(model: TorqueModel, signals: dict[str, np.ndarray],
                             gain: float | np.ndarray = DEFAULT_GAIN,
                             mapping: WrenchMapping = WrenchMapping()
                             ) -> tuple[Diagram, dict[str, VectorLogSink]]:
    """The replay diagram over preprocessed ``signals`` (see :func:`preprocess`). Returns the diagram and its
    loggers keyed ``"<observer>.<port>"``, each sampling every ``signals['time_step']`` from t = 0."""
    n = model.description.n
    h = signals["time_step"]
    builder = DiagramBuilder()
    stacked = np.hstack([signals[k] for k in ("q", "qd", "qdd", "tau")]).T
    source = builder.AddNamedSystem("recording", TrajectorySource(
        PiecewisePolynomial.FirstOrderHold(signals["t"], stacked)))
    demux = builder.AddNamedSystem("signals", Demultiplexer([n, n, n, n]))
    builder.Connect(source.get_output_port(), demux.get_input_port())
    q, qd, qdd, tau = (demux.get_output_port(i) for i in range(4))
    torque_model, jac, mom = AddWrenchObservers(builder, model, h, gain, mapping)
    for port, name in ((q, "q"), (qd, "qd"), (qdd, "qdd")):
        builder.Connect(port, torque_model.GetInputPort(name))
    for obs in (jac, mom):
        builder.Connect(q, obs.GetInputPort("q"))
        builder.Connect(tau, obs.GetInputPort("tau_meas"))
    builder.Connect(qd, mom.GetInputPort("qd"))
    loggers = {}
    for name, obs in (("jacobian", jac), ("momentum", mom)):
        for port in _LOGGED[name]:
            loggers[f"{name}.{port}"] = LogVectorOutput(obs.GetOutputPort(port), builder, publish_period=h)
    return builder.Build(), loggers


@dataclass
class EstimationResult:
    """Wrench estimates over a Recording's samples (world frame at the flange, ``[fx, fy, fz, mx, my, mz]``).

    ``q [N,n]`` the filtered joint positions the observers used; ``wrench[obs]`` ``[N,6]`` and ``tau_ext[obs]``
    ``[N,n]`` per observer (``"jacobian"``, ``"momentum"``);
    ``manipulability [N]`` and ``unreliable [N]`` (bool) of the Jacobian mapping; ``f_true`` the Recording's true
    wrench or None. :meth:`force_stats` skips ``skip_start_s`` at the start (the momentum observer's transient 5/K_O
    and the filters' edge) and ``skip_end_s`` at the end (the zero-phase filters' edge).
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

    def valid(self) -> np.ndarray:
        """Samples used for statistics: away from the start-up and edge transients and not flagged unreliable."""
        return ((self.t >= self.t[0] + self.skip_start_s) & (self.t <= self.t[-1] - self.skip_end_s)
                & ~self.unreliable)

    def force_stats(self, observer: str) -> tuple[np.ndarray, np.ndarray]:
        """RMSE ``[3]`` and standard deviation ``[3]`` [N] of the force error f̂ − f_true per axis (Table 5.4)."""
        if self.f_true is None:
            raise ValueError("force_stats: the recording has no true wrench 'f_ext'")
        mask = self.valid()
        if not mask.any():
            raise ValueError("force_stats: no valid samples (all within the start-up transient or unreliable)")
        err = self.wrench[observer][mask, :3] - self.f_true[mask, :3]
        return np.sqrt(np.mean(err ** 2, axis=0)), np.std(err, axis=0)

    def arrays(self) -> dict[str, np.ndarray]:
        """Flat ``name → array`` view for npz export (read back by :meth:`load`)."""
        out = {"t": self.t, "q": self.q, "manipulability": self.manipulability,
               "unreliable": self.unreliable.astype(float), "skip_s": np.array([self.skip_start_s, self.skip_end_s])}
        for obs in OBSERVERS:
            out[f"wrench_{obs}"] = self.wrench[obs]
            out[f"tau_ext_{obs}"] = self.tau_ext[obs]
        if self.f_true is not None:
            out["f_true"] = self.f_true
        return out

    def save(self, out_dir: str | Path, stem: str = "estimates") -> list[Path]:
        """Write ``<stem>.npz`` (all arrays + ``meta`` JSON) and ``<stem>.csv`` (t, wrenches, flags) atomically."""
        out_dir = Path(out_dir)
        npz, csv = out_dir / f"{stem}.npz", out_dir / f"{stem}.csv"
        with atomic_path(npz) as tmp:
            np.savez_compressed(tmp, **self.arrays(), meta=np.array(json.dumps(self.meta, sort_keys=True)))
        axes = ("fx", "fy", "fz", "mx", "my", "mz")
        columns = [("t", self.t)]
        sources = [(obs, self.wrench[obs]) for obs in OBSERVERS] + ([("true", self.f_true)] if self.f_true is not
                                                                    None else [])
        columns += [(f"{a}_{name}", w[:, i]) for name, w in sources for i, a in enumerate(axes)]
        columns += [("manipulability", self.manipulability), ("unreliable", self.unreliable.astype(float))]
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
                   meta=json.loads(str(data["meta"])))

    def plot(self, path: str | Path, title: str = "") -> Path:
        """PNG of f̂ (both observers) against the true force per axis over time, flagged samples shaded."""
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axs = plt.subplots(3, 1, sharex=True, figsize=(10, 7))
        for i, ax in enumerate(axs):
            if self.f_true is not None:
                ax.plot(self.t, self.f_true[:, i], "k", lw=1.5, label="true")
            for obs, style in zip(OBSERVERS, ("C0", "C1")):
                ax.plot(self.t, self.wrench[obs][:, i], style, lw=0.8, label=obs)
            if self.unreliable.any():
                ax.fill_between(self.t, 0, 1, where=self.unreliable, transform=ax.get_xaxis_transform(),
                                color="r", alpha=0.15, label="unreliable")
            ax.axvspan(self.t[0], self.t[0] + self.skip_start_s, color="0.85", zorder=-1)
            ax.axvspan(self.t[-1] - self.skip_end_s, self.t[-1], color="0.85", zorder=-1)
            ax.set_ylabel(f"f{'xyz'[i]} [N]")
            ax.grid(alpha=0.3)
        axs[0].legend(loc="upper right", ncol=4, fontsize=8)
        axs[-1].set_xlabel("t [s]  (grey: start-up / filter edges, excluded from statistics)")
        fig.suptitle(title or f"external force at the flange (world frame), model {self.meta.get('model', '?')}")
        fig.tight_layout()
        return save_figure(fig, path)


def conditioned_signals(rec: Recording, conditioning: ConditioningConfig = ConditioningConfig()
                        ) -> tuple[Recording, dict[str, np.ndarray], float]:
    """The Recording on its uniform grid, the replayed signals ``t, q, qd, qdd, tau`` (+ ``time_step``) of the one
    conditioning path (:func:`proprio.conditioning.condition`) and the filters' edge transient [s]."""
    cs = condition(rec, conditioning)
    sig = {"t": cs.t, "q": cs.q, "qd": cs.qd, "qdd": cs.qdd, "tau": cs.tau, "time_step": 1.0 / cs.rate_hz}
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
    diagram, loggers = build_estimation_diagram(model, sig, gain, mapping)
    simulator = Simulator(diagram)
    simulator.Initialize()
    simulator.AdvanceTo(float(sig["t"][-1]) + 0.5 * sig["time_step"])
    context = simulator.get_context()
    n_s = rec.n_samples
    logs = {k: lg.FindLog(context).data().T[:n_s] for k, lg in loggers.items()}
    return EstimationResult(
        t=rec.t.copy(), q=sig["q"], wrench={o: logs[f"{o}.wrench"] for o in OBSERVERS},
        tau_ext={o: logs[f"{o}.tau_ext"] for o in OBSERVERS},
        manipulability=logs["jacobian.manipulability"][:, 0], unreliable=logs["jacobian.unreliable"][:, 0] > 0.5,
        f_true=None if rec.f_ext is None else rec.f_ext.copy(), **_skips(gain, edge_s),
        meta=_meta(model, rec, gain, mapping, conditioning, "diagram"))


def estimate_wrench_offline(model: TorqueModel | RobotDescription, rec: Recording,
                            gain: float | np.ndarray = DEFAULT_GAIN,
                            mapping: WrenchMapping = WrenchMapping(),
                    conditioning: ConditioningConfig = ConditioningConfig()
                            ) -> EstimationResult:
    """The same estimates as :func:`estimate_wrench`, vectorised over samples with the observers' offline functions
    (:func:`jacobian_wrench`, :func:`momentum_observer`) instead of stepping the diagram."""
    model, rec, sig, edge_s = _prepare(model, rec, conditioning)
    desc = model.description
    q, qd, qdd, tau = sig["q"], sig["qd"], sig["qdd"], sig["tau"]
    tau_int = model.tau_int(q, qd, qdd)
    tau_dyn = inverse_dynamics(desc, q, qd, qdd) + tau_int
    geo = chain_geometry(desc)
    w_jac, manip, flag = jacobian_wrench(geo, q, tau, tau_dyn, mapping)
    r = momentum_observer(desc, sig["time_step"], q, qd, tau, tau_int, gain)
    w_mom, _, _ = wrench_from_joint_torque(point_jacobian(geo, q, np.asarray(mapping.contact_point)), r, mapping)
    return EstimationResult(
        t=rec.t.copy(), q=q, wrench={"jacobian": w_jac, "momentum": w_mom}, tau_ext={"jacobian": tau_dyn - tau,
                                                                                 "momentum": r},
        manipulability=manip, unreliable=flag, f_true=None if rec.f_ext is None else rec.f_ext.copy(),
        **_skips(gain, edge_s), meta=_meta(model, rec, gain, mapping, conditioning, "offline"))
