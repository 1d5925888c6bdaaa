"""Build a Drake ``MultibodyPlant`` from a :class:`RobotDescription`, and thin single-sample Drake helpers.

One recipe (:func:`add_robot_model`: proprio's URDF of the description and payload, the description's gravity) makes
every plant of the app: :func:`robot_plant` the standalone, finalized plant without geometry that the twin, its
controller and :class:`DrakeRobot` use (reflected rotor inertia or series-spring gains per actuator when asked);
``AddRobot(builder, desc, ...)`` (the ``AddX(builder, ...)`` idiom) the plant + scene graph of a Diagram that draws or
checks collisions. :class:`DrakeRobot` wraps a finalized plant and a context for cross-checks
(``CalcInverseDynamics``, ``CalcJacobianSpatialVelocity``) and one-off queries.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, DiscreteContactApproximation, MultibodyPlant
from pydrake.multibody.tree import MultibodyForces
from pydrake.multibody.tree import JacobianWrtVariable, ModelInstanceIndex, PdControllerGains
from pydrake.systems.framework import DiagramBuilder

from proprio.description import RobotDescription
from proprio.payload import Payload
from proprio.urdf import to_urdf

__all__ = ["RobotPlant", "add_robot_model", "robot_plant", "AddRobot", "build_plant", "DrakeRobot"]


def add_robot_model(plant: MultibodyPlant, desc: RobotDescription, payload: Payload | None = None,
                    collision: bool = True, visual: bool = False) -> ModelInstanceIndex:
    """Parse ``desc`` (and an optional flange ``payload``) into the unfinalized ``plant`` with the description's
    gravity [m/s²]: the one recipe of every plant (``collision``/``visual``: geometry for a scene graph)."""
    instances = Parser(plant).AddModelsFromString(to_urdf(desc, payload, collision=collision, visual=visual), "urdf")
    plant.mutable_gravity_field().set_gravity_vector(np.asarray(desc.gravity, dtype=float))
    return instances[0]


def robot_plant(desc: RobotDescription, payload: Payload | None = None, time_step: float = 0.0,
                rotor_inertia: np.ndarray | None = None, spring_gains: tuple[np.ndarray, np.ndarray] | None = None
                ) -> MultibodyPlant:
    """The robot as a standalone, finalized ``MultibodyPlant`` without geometry (:func:`add_robot_model`).

    Args:
        desc: the robot description.
        payload: optional rigid payload welded to the flange.
        time_step: 0 for a continuous plant, else the discrete period [s]. A discrete plant samples no output ports
            (``SetUseSampledOutputPorts(False)``: q̈ and the net actuation are those of the current state) and uses
            TAMSI — ≈ 2× faster than SAP with nothing in contact — unless ``spring_gains`` need SAP.
        rotor_inertia: reflected rotor inertia per actuator [kg·m²] (Drake's, on the mass matrix' diagonal).
        spring_gains: ``(K, D)`` per actuator [N·m/rad, N·m·s/rad]: each actuator an implicit PD-controlled joint
            (a series-elastic drive's spring; discrete plants only).

    Nothing here needs a SceneGraph: geometry queries would cost ~1/3 of a twin step.
    """
    plant = MultibodyPlant(time_step)
    add_robot_model(plant, desc, payload, collision=False)
    for k, index in enumerate(plant.GetJointActuatorIndices()):
        actuator = plant.get_joint_actuator(index)
        if rotor_inertia is not None:
            actuator.set_default_rotor_inertia(float(rotor_inertia[k]))
        if spring_gains is not None:
            actuator.set_controller_gains(PdControllerGains(p=float(spring_gains[0][k]), d=float(spring_gains[1][k])))
    if time_step > 0:
        plant.SetUseSampledOutputPorts(False)
        plant.set_discrete_contact_approximation(DiscreteContactApproximation.kSap if spring_gains is not None
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
    instance = add_robot_model(plant, desc, payload, visual=visual)
    if finalize:
        plant.Finalize()
    return RobotPlant(plant, scene_graph, instance, desc)


def build_plant(desc: RobotDescription, time_step: float = 0.0, payload: Payload | None = None) -> RobotPlant:
    """A standalone finalized plant (its own builder; the diagram is not built)."""
    return AddRobot(DiagramBuilder(), desc, time_step=time_step, payload=payload)


class DrakeRobot:
    """A finalized continuous plant of ``desc`` with a context, for single-sample Drake queries (SI, world frame)."""

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
