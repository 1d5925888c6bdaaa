"""Collision checking of joint configurations with Drake's SceneGraph (thesis §4.3: scaffolds must be free of
self-collision and of collision with the environment).

The robot's collision primitives come from its description (``Link.collision``, registered by
:func:`proprio.plant.AddRobot`); environment obstacles are :class:`EnvironmentBox` objects registered as anchored
collision geometry on the world body. MultibodyPlant filters pairs of bodies joined by a joint (parent/child) and
bodies welded together, so "self-collision" means two non-adjacent links overlapping.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from pydrake.geometry import Box
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import CoulombFriction
from pydrake.systems.framework import DiagramBuilder

from proprio.description import RobotDescription
from proprio.plant import AddRobot

__all__ = ["EnvironmentBox", "CollisionChecker"]


@dataclass(frozen=True)
class EnvironmentBox:
    """An obstacle box fixed in the world: full extents ``size`` [m], centre ``xyz`` [m], orientation ``rpy``
    [rad] (world frame)."""
    name: str
    size: tuple[float, float, float]
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if len(self.size) != 3 or min(self.size) <= 0.0:
            raise ValueError(f"environment box '{self.name}': size_m must be 3 positive extents, got {self.size}")


class CollisionChecker:
    """SceneGraph collision queries for configurations of ``desc`` among ``boxes``.

    One plant + scene graph diagram is built once; each query sets the joint positions in its context and asks the
    scene graph's ``QueryObject.HasCollisions()`` (broad + narrow phase on the collision primitives).
    """

    def __init__(self, desc: RobotDescription, boxes: Sequence[EnvironmentBox] = ()):
        self.description = desc
        self.boxes = tuple(boxes)
        builder = DiagramBuilder()
        robot = AddRobot(builder, desc, finalize=False)
        plant = robot.plant
        for box in self.boxes:
            plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(RollPitchYaw(box.rpy), box.xyz),
                                            Box(*box.size), f"env_{box.name}", CoulombFriction(0.5, 0.5))
        plant.Finalize()
        self._diagram = builder.Build()
        self._context = self._diagram.CreateDefaultContext()
        self._plant = plant
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._scene_graph = robot.scene_graph
        self._q_index = np.array([plant.GetJointByName(name).position_start() for name in desc.joint_names])
        self._q_full = np.zeros(plant.num_positions())

    def _query(self, q: np.ndarray):
        self._q_full[self._q_index] = q
        self._plant.SetPositions(self._plant_context, self._q_full)
        return self._plant.get_geometry_query_input_port().Eval(self._plant_context)

    def in_collision(self, q: np.ndarray) -> np.ndarray:
        """``bool [N]``: configuration ``q [N,n]`` (or ``[n]``) [rad] has a self- or environment collision."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return np.array([self._query(qi).HasCollisions() for qi in q], dtype=bool)

    def any_collision(self, q: np.ndarray) -> bool:
        """Whether any of the configurations ``q [N,n]`` collides (stops at the first that does)."""
        return any(self._query(qi).HasCollisions() for qi in np.atleast_2d(np.asarray(q, dtype=float)))

    def colliding_pairs(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Names of the penetrating geometry pairs at one configuration ``q [n]`` (for diagnostics)."""
        query = self._query(np.asarray(q, dtype=float))
        inspector = query.inspector()
        return [(inspector.GetName(p.id_A), inspector.GetName(p.id_B))
                for p in query.ComputePointPairPenetration()]
