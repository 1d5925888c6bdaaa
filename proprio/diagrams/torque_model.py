"""The joint-torque models of the estimator: the :class:`TorqueModel` protocol, the rigid-body model of a description
(:class:`RigidBodyTorqueModel`: RBD + link friction + drive terms + offsets) and its System
(:class:`TorqueModelSystem`: C++ ``InverseDynamics`` + :class:`InteractionTorqueSystem`).

Both the estimation diagram (:mod:`proprio.diagrams.estimation`) and the hybrid model
(:mod:`proprio.diagrams.hybrid_torque_model`, whose backbone is a :class:`RigidBodyTorqueModel`) import this module;
neither imports the other at module level. The per-sample law of τ_int is :meth:`RigidBodyTorqueModel.tau_int_step`,
the batch law :meth:`RigidBodyTorqueModel.tau_int`: both evaluate the same functions
(:func:`proprio.friction_law.viscous_coulomb`, :func:`~proprio.identification.regressor.drive_torque`), the step with
its constants folded.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import numpy as np
from pydrake.systems.controllers import InverseDynamics
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Adder, Multiplexer

from proprio import friction_law
from proprio.description import RobotDescription, load_robot
from proprio.identification.model_io import load_model
from proprio.identification.regressor import drive_identified, drive_torque
from proprio.plant import DrakeRobot

__all__ = ["TorqueModel", "RigidBodyTorqueModel", "load_rigid_torque_model", "InteractionTorqueSystem",
           "TorqueModelSystem"]


class TorqueModel(Protocol):
    """A joint-torque model τ_dyn = τ_rbd + τ_int (eq. 3.9), vectorised over samples ``[N,n]``.

    ``description`` gives the kinematics and the rigid-body inertials: τ_rbd is its inverse dynamics (Drake's
    ``CalcInverseDynamics`` per step in the diagram, :func:`proprio.dynamics.inverse_dynamics` offline) and the
    momentum observer takes M(q) from it. ``tau_int`` is everything the model adds to the rigid body (link friction,
    a learned residual).

    A model with memory (the hybrid model, :mod:`proprio.diagrams.hybrid_torque_model`) also provides
    ``make_system(time_step) -> System`` (the ports of :class:`TorqueModelSystem`, run online by the diagram instead of
    it) and ``signals(rec) -> (Recording, signals)`` (its own preprocessing at its own rate, instead of
    :func:`~proprio.diagrams.estimation.conditioned_signals`; ``signals["edge_s"]`` is its filters' edge transient [s]) and a ``name``."""
    description: RobotDescription

    def tau_int(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class RigidBodyTorqueModel:
    """The RBD model of a description plus its link-side viscous + Coulomb friction, if it has any, and constant
    torque offsets: ``τ_int = F_v q̇ + F_c sgn(q̇) + τ_offset`` [N·m], the one law of :mod:`proprio.friction_law` with
    ``sgn = tanh(q̇ / coulomb_velocity)`` (``np.sign`` when 0; ``None``: the library's smoothing, read when
    evaluated). A drive-torque arm (``drive.tau_kind: drive``) adds its drive terms, rotor inertia on q̈ and motor
    friction on the coupled motor velocity (:func:`~proprio.identification.regressor.drive_torque`), and takes the
    drive block's offsets when none are given: the observers then see the link-side torque in τ − τ_int."""
    description: RobotDescription
    coulomb_velocity: float | None = None
    offset: tuple[float, ...] | None = None

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
        """τ_int ``[N,n]`` [N·m] for ``q, qd, qdd [N,n]`` (rad, rad/s, rad/s²; q is not read)."""
        d = self.description
        qd = np.asarray(qd, dtype=float)
        tau = np.broadcast_to(self._offset(), qd.shape).copy()
        if drive_identified(d):
            tau += drive_torque(d, qd, qdd, self.coulomb_velocity)
        if d.has_friction:
            tau += friction_law.viscous_coulomb(qd, np.asarray(d.friction_viscous), np.asarray(d.friction_coulomb),
                                                self.coulomb_velocity)
        return tau

    def tau_int_step(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """The same ``τ_int(q̇, q̈)`` [N·m] for ONE sample ``q̇, q̈ [n]``, constants folded (for the per-step Systems
        and the streaming estimator). q̈ matters only for a drive-torque arm (rotor inertia)."""
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


def load_rigid_torque_model(spec: str | Path) -> RigidBodyTorqueModel:
    """A rigid-body model from a shipped robot name or robot YAML/URDF (its RBD + friction, e.g.
    ``iiwa14_identified``) or an identified-model ``.npz`` from ``proprio identify`` (its identified inertials,
    friction, Coulomb law and torque offsets; Drake must accept the identified inertials, which an SDP model always
    satisfies)."""
    path = Path(spec)
    if path.suffix == ".npz":
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


class InteractionTorqueSystem(LeafSystem):
    """``tau_int`` (n) [N·m] = the model's τ_int for one sample of the inputs ``q`` [rad], ``qd`` [rad/s], ``qdd``
    [rad/s²]: the per-sample law of a :class:`RigidBodyTorqueModel` (``tau_int_step``), the model's vectorised
    ``tau_int`` on one row otherwise. :meth:`calc` is the step function."""

    def __init__(self, model: TorqueModel):
        LeafSystem.__init__(self)
        n = model.description.n
        self._ports = [self.DeclareVectorInputPort(name, n) for name in ("q", "qd", "qdd")]
        if hasattr(model, "tau_int_step"):
            step = model.tau_int_step()
            self.calc = lambda q, qd, qdd: step(qd, qdd)
            self._ports[0] = None                       # the rigid-body law does not read q, nor q̈ but for a drive arm
            if not model.reads_qdd:
                self._ports[2] = None
        else:
            self.calc = lambda q, qd, qdd: model.tau_int(q[None, :], qd[None, :], qdd[None, :])[0]
        self.DeclareVectorOutputPort("tau_int", n, self._calc)

    def _calc(self, context, output) -> None:
        output.SetFromVector(self.calc(*(None if p is None else p.Eval(context) for p in self._ports)))


class TorqueModelSystem(Diagram):
    """A :class:`TorqueModel` as a sub-Diagram: τ_rbd from Drake's C++ ``InverseDynamics`` (gravity as the applied
    force) and τ_int from :class:`InteractionTorqueSystem`::

        q, qd ──▶ Multiplexer ──▶ InverseDynamics ──τ_rbd──▶ Adder ──▶ tau_dyn
        qdd ───────────────────────────┘                ┌──▶ ┘
        q, qd, qdd ──▶ InteractionTorqueSystem ──tau_int┴────────────▶ tau_int

    Inputs ``q``, ``qd``, ``qdd`` (n each, rad, rad/s, rad/s²); outputs ``tau_dyn`` = τ_rbd + τ_int, ``tau_int`` and
    ``tau_rbd`` (n each, N·m). ``arm`` is the plant the C++ system evaluates (kept alive with it)."""

    def __init__(self, model: TorqueModel):
        Diagram.__init__(self)
        n = model.description.n
        self.arm = DrakeRobot(model.description)
        builder = DiagramBuilder()
        state = builder.AddNamedSystem("state", Multiplexer([n, n]))
        self.rbd = builder.AddNamedSystem("rigid_body", InverseDynamics(self.arm.plant))
        self.interaction = builder.AddNamedSystem("interaction", InteractionTorqueSystem(model))
        total = builder.AddNamedSystem("total", Adder(2, n))
        builder.ExportInput(state.get_input_port(0), "q")
        builder.ExportInput(state.get_input_port(1), "qd")
        builder.ExportInput(self.rbd.get_input_port_desired_acceleration(), "qdd")
        for name in ("q", "qd", "qdd"):
            builder.ConnectInput(name, self.interaction.GetInputPort(name))
        builder.Connect(state.get_output_port(), self.rbd.get_input_port_estimated_state())
        builder.Connect(self.rbd.get_output_port_generalized_force(), total.get_input_port(0))
        builder.Connect(self.interaction.get_output_port(), total.get_input_port(1))
        builder.ExportOutput(total.get_output_port(), "tau_dyn")
        builder.ExportOutput(self.interaction.get_output_port(), "tau_int")
        builder.ExportOutput(self.rbd.get_output_port_generalized_force(), "tau_rbd")
        builder.BuildInto(self)
        self.set_name("torque_model")
