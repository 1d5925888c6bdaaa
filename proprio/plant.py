"""The one plant factory: a Drake ``MultibodyPlant`` from a :class:`RobotDescription` (+ payload), and thin
single-sample Drake helpers.

Every plant of the app is made here from one URDF text per (description, payload), generated once and cached
(:func:`robot_urdf`):

* :func:`robot_plant` — a finalized plant without a SceneGraph (the twin's discrete plant and its controller's model);
* ``AddRobot(builder, desc, ...)`` (the ``AddX(builder, ...)`` idiom) — plant + scene graph in a ``DiagramBuilder``
  (collision checking, drawing);
* :func:`drake_robot` — the cached :class:`DrakeRobot` of a (description, payload): a finalized continuous plant and
  a context for cross-checks (``CalcInverseDynamics``, ``CalcJacobianSpatialVelocity``) and one-off queries, parsed
  once per process.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, DiscreteContactApproximation, MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable, ModelInstanceIndex, MultibodyForces, PdControllerGains
from pydrake.systems.framework import DiagramBuilder

from proprio.description import RobotDescription
from proprio.payload import Payload
from proprio.urdf import to_urdf

__all__ = ["RobotPlant", "AddRobot", "build_plant", "DrakeRobot", "robot_urdf", "robot_plant", "drake_robot"]


@functools.lru_cache(maxsize=64)
def robot_urdf(desc: RobotDescription, payload: Payload | None = None, collision: bool = False,
               visual: bool = False) -> str:
    """The URDF text of ``desc`` (+ ``payload`` welded to the flange), generated once per argument set
    (:func:`proprio.urdf.to_urdf`)."""
    return to_urdf(desc, payload, collision=collision, visual=visual)


def robot_plant(desc: RobotDescription, payload: Payload | None = None, time_step: float = 0.0,
                rotor_inertia: np.ndarray | None = None,
                spring: tuple[np.ndarray, np.ndarray] | None = None) -> MultibodyPlant:
    """A finalized ``MultibodyPlant`` of ``desc`` (+ ``payload``), no collision shapes, no SceneGraph (a plant that
    plays planned, collision-free motion needs no geometry queries: they would cost ~1/3 of a step).

    ``time_step`` 0 → continuous, else the discrete period [s]; ``rotor_inertia`` [kg·m²] per actuator (reflected
    motor inertia, implicit); ``spring`` = (K [N·m/rad], D [N·m·s/rad]) per actuator makes each actuator a
    PD-controlled joint (the series spring of an elastic drive; needs SAP). A discrete plant's output ports are
    those of the current state (not sampled), and without a spring it uses TAMSI (≈2× faster than SAP when nothing
    is in contact)."""
    plant = MultibodyPlant(time_step)
    Parser(plant).AddModelsFromString(robot_urdf(desc, payload), "urdf")
    plant.mutable_gravity_field().set_gravity_vector(np.asarray(desc.gravity, dtype=float))
    for k, index in enumerate(plant.GetJointActuatorIndices()):
        actuator = plant.get_joint_actuator(index)
        if rotor_inertia is not None:
            actuator.set_default_rotor_inertia(float(rotor_inertia[k]))
        if spring is not None:
            actuator.set_controller_gains(PdControllerGains(p=float(spring[0][k]), d=float(spring[1][k])))
    if time_step > 0:
        plant.SetUseSampledOutputPorts(False)
        plant.set_discrete_contact_approximation(DiscreteContactApproximation.kSap if spring is not None
                                                 else DiscreteContactApproximation.kTamsi)
    plant.Finalize()
    return plant


@dataclass
class RobotPlant:
    """What :func:`AddRobot` returns: the plant, its scene graph and the robot's model instance."""
    plant: MultibodyPlant
    scene_graph: object
    instance: ModelInstanceIndex
    description: RobotDescription


def AddRobot(builder: DiagramBuilder, desc: RobotDescription, time_step: float = 0.0,
             payload: Payload | None = None, finalize: bool = True, visual: bool = False) -> RobotPlant:
    """Add ``desc`` (and an optional flange ``payload``) to ``builder`` as a MultibodyPlant + SceneGraph.

    Args:
        builder: the diagram builder to add to.
        desc: the robot description.
        time_step: 0 for a continuous plant, else the discrete update period [s] (e.g. 1e-3).
        payload: optional rigid payload welded to the flange.
        finalize: finalize the plant (set False to add more bodies first).
        visual: also register simple visual geometry (:func:`proprio.urdf.visual_shapes`), for Meshcat.
    """
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=time_step)
    instances = Parser(plant).AddModelsFromString(robot_urdf(desc, payload, collision=True, visual=visual), "urdf")
    plant.mutable_gravity_field().set_gravity_vector(np.asarray(desc.gravity, dtype=float))
    if finalize:
        plant.Finalize()
    return RobotPlant(plant, scene_graph, instances[0], desc)


def build_plant(desc: RobotDescription, time_step: float = 0.0, payload: Payload | None = None) -> RobotPlant:
    """A standalone finalized plant (its own builder; the diagram is not built)."""
    return AddRobot(DiagramBuilder(), desc, time_step=time_step, payload=payload)


class DrakeRobot:
    """A finalized continuous plant of ``desc`` with a context, for single-sample Drake queries (SI, world frame).
    :func:`drake_robot` gives the cached one of a (description, payload)."""

    def __init__(self, desc: RobotDescription, payload: Payload | None = None):
        self.description = desc
        self.plant = robot_plant(desc, payload)
        self.context = self.plant.CreateDefaultContext()
        self.flange = self.plant.GetFrameByName(desc.end_effector.name)
        self._world, self._origin = self.plant.world_frame(), np.zeros(3)
        self.joints = [self.plant.GetJointByName(j.name) for j in desc.joints]
        self._q_index = np.array([j.position_start() for j in self.joints])
        self._v_index = np.array([j.velocity_start() for j in self.joints])
        # the common case: the arm's joints are the plant's whole state, in order (no re-indexing per call)
        self._in_order = (self.plant.num_positions() == self.plant.num_velocities() == desc.n
                          and np.array_equal(self._q_index, np.arange(desc.n))
                          and np.array_equal(self._v_index, np.arange(desc.n)))
        self._forces = MultibodyForces(self.plant)                # reused by inverse_dynamics

    def _set(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Set the joint positions and, when given, velocities (position-only queries leave velocities alone)."""
        if self._in_order:
            self.plant.SetPositions(self.context, q)
            if qd is not None:
                self.plant.SetVelocities(self.context, qd)
            return
        q_full = np.zeros(self.plant.num_positions())
        q_full[self._q_index] = q
        self.plant.SetPositions(self.context, q_full)
        if qd is not None:
            v_full = np.zeros(self.plant.num_velocities())
            v_full[self._v_index] = qd
            self.plant.SetVelocities(self.context, v_full)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """``CalcInverseDynamics`` with gravity as the only applied force [N·m] (eq. 3.5 without friction)."""
        self._set(q, qd)
        forces = self._forces
        self.plant.CalcForceElementsContribution(self.context, forces)  # gravity (overwrites the previous call's)
        if self._in_order:
            return self.plant.CalcInverseDynamics(self.context, qdd, forces)
        a = np.zeros(self.plant.num_velocities())
        a[self._v_index] = qdd
        return self.plant.CalcInverseDynamics(self.context, a, forces)[self._v_index]

    def flange_pose(self, q: np.ndarray) -> np.ndarray:
        """4×4 world pose of the flange frame."""
        self._set(q)
        return self.flange.CalcPoseInWorld(self.context).GetAsMatrix4()

    def flange_jacobian(self, q: np.ndarray, p_flange: np.ndarray | None = None) -> np.ndarray:
        """``CalcJacobianSpatialVelocity`` of a point in the flange frame, expressed in world, ``[6,n]``."""
        self._set(q)
        p = self._origin if p_flange is None else p_flange
        jac = self.plant.CalcJacobianSpatialVelocity(self.context, JacobianWrtVariable.kV, self.flange, p,
                                                     self._world, self._world)
        return jac if self._in_order else jac[:, self._v_index]

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        self._set(q)
        return self.plant.CalcMassMatrix(self.context)[np.ix_(self._v_index, self._v_index)]


@functools.lru_cache(maxsize=16)
def drake_robot(desc: RobotDescription, payload: Payload | None = None) -> DrakeRobot:
    """The :class:`DrakeRobot` of ``desc`` (+ ``payload``), parsed once per process (its context is shared: use it
    from one thread)."""
    return DrakeRobot(desc, payload)
