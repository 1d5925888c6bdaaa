"""Robot descriptions: the YAML robot format, its validating loader, and imports from MDH tables and URDF.

A :class:`RobotDescription` is a serial chain of revolute joints. Frames follow URDF semantics:

* ``T_parent_joint = Translation(origin_xyz) · Rz(yaw) Ry(pitch) Rx(roll)`` with ``origin_rpy = [roll, pitch, yaw]``;
  the child link frame is the joint frame rotated by ``q`` about the unit ``axis`` (expressed in the joint frame).
* Link inertials: ``mass`` [kg], ``com_xyz`` [m] in the link frame, ``inertia_com`` [kg·m²] about the CoM in a frame
  rotated by ``com_rpy`` from the link frame, stored as ``(ixx, iyy, izz, ixy, ixz, iyz)``.
* Angles are radians everywhere except where a key ends in ``_deg`` (converted here, at the boundary).

The YAML layout (``format: proprio-robot/v1``) is documented in ``docs/guide/robots.md`` and is a superset of the
``robot-numbers/v1`` layout of ``../shared/data/kuka_lwr4/robot.yaml``, so that file loads directly.

The package's modules: :mod:`~proprio.description.model` (the dataclasses), :mod:`~proprio.description.fields` (the
YAML fields and their validating readers), :mod:`~proprio.description.mdh` (modified-DH tables) and
:mod:`~proprio.description.loader` (by name, file or directory). Import from here.
"""
from proprio.description.fields import DOC_KEYS, check_keys
from proprio.description.loader import builtin_robots, load_robot, robot_from_dict, robot_from_urdf
from proprio.description.mdh import robot_from_mdh
from proprio.description.model import (INERTIA_KEYS, CollisionShape, DescriptionError, DescriptionWarning, EndEffector,
                                       Joint, Link, RobotDescription, matrix_to_rpy, rpy_to_matrix)

__all__ = [
    "CollisionShape", "Joint", "Link", "EndEffector", "RobotDescription", "DescriptionError", "DescriptionWarning",
    "load_robot", "robot_from_dict", "robot_from_mdh", "robot_from_urdf", "builtin_robots", "rpy_to_matrix",
    "check_keys", "matrix_to_rpy", "INERTIA_KEYS", "DOC_KEYS",
]
