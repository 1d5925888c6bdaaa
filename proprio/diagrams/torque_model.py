"""The joint-torque models of the estimator: the :class:`TorqueModel` protocol, the rigid-body model of a description
(:class:`RigidBodyTorqueModel`: RBD + link friction + drive terms + offsets), its per-sample torque law
(:class:`RigidTorqueStep`) and the System of that law (:class:`TorqueModelSystem`, on the τ_rigid of the
estimator's RBD stage, :class:`~proprio.systems.momentum_observer.RigidBodyTermsSystem`: with it, the RBD backbone
τ_RBD of the design card).

Both the estimation diagram (:mod:`proprio.diagrams.estimation`) and the hybrid model
(:mod:`proprio.diagrams.hybrid_torque_model`, whose backbone is a :class:`RigidBodyTorqueModel`) import this module;
neither imports the other at module level. The per-sample law of τ_int is :meth:`RigidBodyTorqueModel.tau_int_step`,
the batch law :meth:`RigidBodyTorqueModel.tau_int`: both evaluate the same functions
(:func:`proprio.friction_law.viscous_coulomb`, :func:`~proprio.identification.regressor.drive_torque`), the step with
its constants folded. An identified model with the torque sensor's terms (``proprio identify --sensor-terms``,
:mod:`proprio.identification.sensor_terms`) has state — the reversal state of its hysteresis and lost motion —
which the step carries as its memory (a ``ZeroOrderHold`` in :class:`TorqueModelSystem`) and the batch law over one
contiguous sequence from its first sample: the same law, to rounding (tests).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, Multiplexer, ZeroOrderHold

from proprio import friction_law
from proprio.description import RobotDescription, load_robot
from proprio.dynamics import inverse_dynamics
from proprio.identification.model_io import load_model
from proprio.identification.sensor_terms import SensorCarry, SensorTerms
from proprio.identification.regressor import drive_identified, drive_torque
from proprio.plant import DrakeRobot

__all__ = ["TorqueModel", "RigidBodyTorqueModel", "load_rigid_torque_model", "RigidTorqueStep", "TorqueStepSystem",
           "TorqueModelSystem"]


class TorqueModel(Protocol):
    """A joint-torque model τ_dyn = τ_rbd + τ_int (eq. 3.9), vectorised over samples ``[N,n]``.

    ``description`` gives the kinematics and the rigid-body inertials: τ_rbd is its inverse dynamics (per step from
    the RBD stage's plant context, :class:`~proprio.rigid_body_terms.RigidBodyTerms`, which gives the momentum
    observer M(q) from the same kinematics; :func:`proprio.dynamics.inverse_dynamics` offline). ``tau_int`` is everything the model adds to the rigid body (link friction,
    a learned residual).

    ``torque_step()`` is its per-sample law (``n``, ``memory_size``, ``initial_memory()``, ``step_into(inputs,
    memory, out, memory_out)``: :class:`RigidTorqueStep`), which the streaming estimator calls, and
    :class:`TorqueModelSystem` for a memoryless law. A model with its own preprocessing (the hybrid model,
    :mod:`proprio.diagrams.hybrid_torque_model`) also provides ``signals(rec) -> (Recording, signals)`` (its own
    preprocessing at its own rate, instead of :func:`~proprio.diagrams.estimation.conditioned_signals`;
    ``signals["edge_s"]`` is its filters' edge transient [s]) and a ``name``; a hybrid model also ``backbone`` (its
    :class:`RigidBodyTorqueModel`) and ``network`` (its :class:`~proprio.learning.models.HybridModel`), which the
    estimation Diagram runs as two stages."""
    description: RobotDescription

    def tau_int(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray: ...

    def torque_step(self) -> "RigidTorqueStep": ...


@dataclass(frozen=True)
class RigidBodyTorqueModel:
    """The RBD model of a description plus its link-side viscous + Coulomb friction, if it has any, and constant
    torque offsets: ``τ_int = F_v q̇ + F_c sgn(q̇) + τ_offset`` [N·m], the one law of :mod:`proprio.friction_law` with
    ``sgn = tanh(q̇ / coulomb_velocity)`` (``np.sign`` when 0; ``None``: the library's smoothing, read when
    evaluated). A drive-torque arm (``drive.tau_kind: drive``) adds its drive terms, rotor inertia on q̈ and motor
    friction on the coupled motor velocity (:func:`~proprio.identification.regressor.drive_torque`), and takes the
    drive block's offsets when none are given: the observers then see the link-side torque in τ − τ_int.

    ``load_gain``: identified load gains ``k [n]`` [-] of load-dependent Coulomb friction (``proprio identify
    --load-friction``), on the whole torque as the identified model applies them
    (:meth:`~proprio.identification.model_io.IdentifiedModel.torque`): ``τ_dyn`` is the root of ``τ_dyn − k|τ_dyn|
    sgn_s(q̇) = τ_rigid + τ_int(without it)`` (:func:`proprio.friction_law.load_from_net`), so τ_int reads τ_rigid.
    ``sensor``: identified torque-sensor terms (:mod:`proprio.identification.sensor_terms`) added to τ_int after it,
    on the a-priori description ``prior``'s rigid body and friction (the identification's ``Y φ_prior``: the gain's
    column and the load); they have state (module docstring)."""
    description: RobotDescription
    coulomb_velocity: float | None = None
    offset: tuple[float, ...] | None = None
    sensor: SensorTerms | None = None
    prior: RobotDescription | None = None
    load_gain: tuple[float, ...] | None = None

    @property
    def reads_qdd(self) -> bool:
        """Whether τ_int depends on q̈ (a drive-torque arm's rotor inertia)."""
        return drive_identified(self.description)

    def _offset(self) -> np.ndarray:
        """The constant torque offsets [N·m] (n): the given ones, else a drive arm's drive block's, else zeros."""
        d = self.description
        offset = d.drive.offset if self.offset is None and self.reads_qdd else self.offset
        return np.zeros(d.n) if offset is None else np.asarray(offset, dtype=float)

    def tau_int(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ_int ``[N,n]`` [N·m] for ``q, qd, qdd [N,n]`` (rad, rad/s, rad/s²; q is read only by the load gains and
        the sensor terms)."""
        d = self.description
        qd = np.asarray(qd, dtype=float)
        tau = np.broadcast_to(self._offset(), qd.shape).copy()
        if drive_identified(d):
            tau += drive_torque(d, qd, qdd, self.coulomb_velocity)
        if d.has_friction:
            tau += friction_law.viscous_coulomb(qd, np.asarray(d.friction_viscous), np.asarray(d.friction_coulomb),
                                                self.coulomb_velocity)
        q, qdd = np.asarray(q, dtype=float), np.asarray(qdd, dtype=float)
        if self.load_gain is not None:
            tau = self.with_load_friction(inverse_dynamics(d, q, qd, qdd), tau, qd)
        if self.sensor is not None:
            tau += self.sensor.torque(q, qd, self.prior_torque(q, qd, qdd))[0]
        return tau

    def with_load_friction(self, rigid: np.ndarray, tau_int: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """τ_int ``[..., n]`` [N·m] with the load-dependent friction of :attr:`load_gain` on the torque ``rigid +
        τ_int`` it is the root of (:func:`proprio.friction_law.load_from_net`; ``rigid`` τ_rigid [N·m], ``qd``
        [rad/s], the same shape): the one place the batch and the step apply it."""
        sign = friction_law.smooth_sign(qd, self.coulomb_velocity)
        return friction_law.load_from_net(rigid + tau_int, sign, np.asarray(self.load_gain)) - rigid

    def prior_torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     rigid: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None) -> np.ndarray:
        """The a-priori description's rigid body and friction ``[N,n]`` [N·m] (the sensor terms' gain column and
        load); ``rigid`` its inverse dynamics (default the numpy RNEA over samples; the step passes a Drake plant's,
        the same law to rounding)."""
        p = self.prior
        tau = inverse_dynamics(p, q, qd, qdd) if rigid is None else rigid(q, qd, qdd)
        if p.has_friction:
            tau = tau + friction_law.viscous_coulomb(qd, np.asarray(p.friction_viscous),
                                                     np.asarray(p.friction_coulomb), self.coulomb_velocity)
        return tau

    def tau_int_step(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """The same ``τ_int(q̇, q̈)`` [N·m] for ONE sample ``q̇, q̈ [n]``, constants folded (for the per-step Systems
        and the streaming estimator), without the load gains and the sensor terms (they read τ_rigid and q:
        :class:`RigidTorqueStep` adds them). q̈ matters only for a drive-torque arm (rotor inertia)."""
        d = self.description
        drive, offset = self.reads_qdd, self._offset()
        v_s = friction_law.smoothing(self.coulomb_velocity)
        fv, fc = np.asarray(d.friction_viscous, dtype=float), np.asarray(d.friction_coulomb, dtype=float)
        if drive:
            link = (lambda qd: friction_law.viscous_coulomb(qd, fv, fc, v_s)) if d.has_friction else \
                (lambda qd: 0.0)
            return lambda qd, qdd: offset + drive_torque(d, qd, qdd, self.coulomb_velocity) + link(qd)
        if not d.has_friction:
            return lambda qd, qdd: offset.copy()
        return lambda qd, qdd: offset + friction_law.viscous_coulomb(qd, fv, fc, v_s)

    def torque_step(self) -> "RigidTorqueStep":
        """The per-sample torque law (:class:`RigidTorqueStep`) of the Systems and the streaming estimator."""
        return RigidTorqueStep(self)


def load_rigid_torque_model(spec: str | Path) -> RigidBodyTorqueModel:
    """A rigid-body model from a shipped robot name or robot YAML/URDF (its RBD + friction, e.g.
    ``iiwa14_identified``) or an identified-model ``.npz`` from ``proprio identify`` (its identified inertials,
    friction, Coulomb law, torque offsets, load gains and sensor terms; Drake must accept the identified inertials,
    which an SDP model always satisfies)."""
    path = Path(spec)
    if path.suffix == ".npz":
        ident = load_model(path)
        model = RigidBodyTorqueModel(ident.description_identified(), ident.coulomb_velocity_scale,
                                     tuple(float(x) for x in ident.offsets), ident.sensor_terms,
                                     ident.description if ident.sensor is not None else None,
                                     tuple(float(x) for x in ident.load_gain) if "load_gain" in ident.extras
                                     else None)
        try:
            DrakeRobot(model.description)
        except (RuntimeError, ValueError) as exc:
            raise ValueError(f"{path}: Drake cannot build a plant from the identified inertials "
                             f"({str(exc).splitlines()[0]}); identify with --method sdp for a physically consistent "
                             "model") from None
        return model
    return RigidBodyTorqueModel(load_robot(spec))


class RigidTorqueStep:
    """The per-sample torque law of a :class:`RigidBodyTorqueModel`: :meth:`step_into` ``[τ_rigid; q; q̇; q̈] →
    [τ_dyn = τ_rigid + τ_int; τ_int]`` with the folded τ_int (:meth:`RigidBodyTorqueModel.tau_int_step`), the load
    gains on τ_rigid (:meth:`RigidBodyTorqueModel.with_load_friction`) and, with sensor terms, their law on the
    one-sample piece continuing the memory ``[started; SensorCarry (9n)]`` (zeros: the first sample starts the
    virgin state, as the batch law's first sample does); no memory without."""

    def __init__(self, model: RigidBodyTorqueModel):
        self.n = n = model.description.n
        self._tau_int = model.tau_int_step()
        self._model, self._sensor = model, model.sensor
        self.memory_size = 0 if model.sensor is None else 1 + 9 * n
        self._prior_id = None if model.sensor is None else DrakeRobot(model.prior).inverse_dynamics   # one sample

    def initial_memory(self) -> np.ndarray:
        return np.zeros(self.memory_size)

    def step_into(self, inputs: np.ndarray, memory: np.ndarray, out: np.ndarray, memory_out: np.ndarray) -> None:
        """``inputs = [τ_rigid; q; q̇; q̈]`` (4n: N·m, rad, rad/s, rad/s²) and ``memory`` → ``out = [τ_dyn; τ_int]``
        (2n, N·m) and the next memory into ``memory_out`` (which must not alias ``memory``)."""
        n = self.n
        tau_int = self._tau_int(inputs[2 * n:3 * n], inputs[3 * n:])
        if self._model.load_gain is not None:
            tau_int = self._model.with_load_friction(inputs[:n], tau_int, inputs[2 * n:3 * n])
        if self._sensor is not None:
            q, qd, qdd = (inputs[k * n:(k + 1) * n] for k in (1, 2, 3))
            carry = SensorCarry.from_vector(memory[1:]) if memory[0] else None
            prior = self._model.prior_torque(q, qd, qdd, self._prior_id)
            tau_s, end = self._sensor.torque(q[None], qd[None], prior[None], carry)
            tau_int = tau_int + tau_s[0]
            memory_out[0] = 1.0
            memory_out[1:] = end.vector()
        np.add(inputs[:n], tau_int, out=out[:n])
        out[n:] = tau_int


class TorqueStepSystem(LeafSystem):
    """The Python System of :class:`TorqueModelSystem`: input ``inputs`` = ``[τ_rigid; q; q̇; q̈; memory]`` (one
    stacked port: each input evaluation from Python costs about a microsecond), output ``step`` = ``[τ_dyn; τ_int;
    next memory]`` — the model's torque step law (``step_into``), nothing else (stateless: the memory comes back
    through a hold)."""

    def __init__(self, law):
        LeafSystem.__init__(self)
        n, size = law.n, law.memory_size
        self._law, self._k = law, 4 * n
        self._inputs = self.DeclareVectorInputPort("inputs", 4 * n + size)
        self.DeclareVectorOutputPort("step", 2 * n + size, self._calc)
        self._out = np.empty(2 * n + size)
        self._tau, self._next = self._out[:2 * n], self._out[2 * n:]

    def _calc(self, context, output) -> None:
        x, k = self._inputs.Eval(context), self._k
        self._law.step_into(x[:k], x[k:], self._tau, self._next)
        output.SetFromVector(self._out)


class TorqueModelSystem(Diagram):
    """A rigid-body model's torque on the estimator's rigid-body torque (the backbone stage), as a sub-Diagram::

        tau_rigid, q, qd, qdd ─▶ Multiplexer ─▶ TorqueStepSystem ─▶ Demultiplexer ─▶ tau_dyn, tau_int
                                      ▲                    └─ next memory ─▶ ZeroOrderHold (period_s) ─┐
                                      └────────────────────────────────────────────────────────────────┘

    Inputs ``tau_rigid`` (the inverse dynamics of the RBD stage, N·m), ``q``, ``qd``, ``qdd`` (rad, rad/s, rad/s²),
    n each; outputs ``tau_dyn`` = τ_rigid + τ_int and ``tau_int`` (N·m), direct feedthrough. The step is the
    model's law (``model.torque_step()``: :class:`RigidTorqueStep`); a law with memory (sensor terms) keeps it in a
    C++ ``ZeroOrderHold`` sampled every ``period_s`` [s] (the estimator's step; zeros at start), as the residual
    network does. A hybrid model is not one stage: the estimation Diagram runs its backbone here and its network as
    the next stage (:class:`~proprio.systems.residual_network.ResidualNetworkSystem`)."""

    def __init__(self, model: TorqueModel, period_s: float | None = None):
        Diagram.__init__(self)
        n = model.description.n
        self.law = law = model.torque_step()
        size = law.memory_size
        if size and getattr(model, "network", None) is not None:
            raise ValueError("TorqueModelSystem: a hybrid model's torque law holds its network's memory; give its "
                             "rigid-body backbone, and run the network as its own System")
        if size and not (period_s is not None and period_s > 0):
            raise ValueError(f"TorqueModelSystem: the model's torque law has memory (sensor terms): give period_s > "
                             f"0 s, the step it is sampled at (got {period_s})")
        builder = DiagramBuilder()
        inputs = builder.AddNamedSystem("inputs", Multiplexer([n] * 4 + ([size] if size else [])))
        step = builder.AddNamedSystem("step", TorqueStepSystem(law))
        split = builder.AddNamedSystem("split", Demultiplexer([n, n] + ([size] if size else [])))
        for i, name in enumerate(("tau_rigid", "q", "qd", "qdd")):
            builder.ExportInput(inputs.get_input_port(i), name)
        builder.Connect(inputs.get_output_port(), step.get_input_port())
        builder.Connect(step.get_output_port(), split.get_input_port())
        if size:
            hold = builder.AddNamedSystem("memory", ZeroOrderHold(float(period_s), size))
            builder.Connect(split.get_output_port(2), hold.get_input_port())
            builder.Connect(hold.get_output_port(), inputs.get_input_port(4))
        builder.ExportOutput(split.get_output_port(0), "tau_dyn")
        builder.ExportOutput(split.get_output_port(1), "tau_int")
        builder.BuildInto(self)
        self.set_name("torque_model")
