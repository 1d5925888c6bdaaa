"""Forward kinematics and the geometric flange Jacobian, vectorised over samples (numpy).

Conventions: ``q`` has shape ``[N, n]`` (or ``[n]``), radians. Poses are 4×4 homogeneous transforms of a frame in the
*world* frame. The geometric Jacobian ``J = [Jω; Jv]`` (rows: angular then translational, Drake's spatial-velocity
order) maps ``q̇`` to the flange's spatial velocity in the world frame, translational part of the flange origin.
Cross-checked against Drake's ``CalcRelativeTransform`` / ``CalcJacobianSpatialVelocity`` in ``tests/``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from proprio.description import RobotDescription, rpy_to_matrix

__all__ = ["ChainGeometry", "chain_geometry", "axis_rotation", "link_poses", "flange_pose", "flange_position",
           "flange_jacobian", "point_jacobian"]


def _homogeneous(xyz, rpy) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rpy_to_matrix(rpy)
    t[:3, 3] = xyz
    return t


@dataclass(frozen=True)
class ChainGeometry:
    """Constant transforms of a serial chain, precomputed once per description."""
    world_base: np.ndarray        # [4,4] world ← base link
    joint_origins: np.ndarray     # [n,4,4] parent link ← joint frame (before rotation)
    axes: np.ndarray              # [n,3] unit joint axes in the joint frame
    flange: np.ndarray            # [4,4] last link ← flange
    gravity: np.ndarray           # [3] world gravity [m/s²]


def chain_geometry(desc: RobotDescription) -> ChainGeometry:
    """Precompute the constant transforms of ``desc``."""
    return ChainGeometry(
        world_base=_homogeneous(desc.world_to_base_xyz, desc.world_to_base_rpy),
        joint_origins=np.stack([_homogeneous(j.origin_xyz, j.origin_rpy) for j in desc.joints]),
        axes=np.array([j.axis for j in desc.joints]),
        flange=_homogeneous(desc.end_effector.xyz, desc.end_effector.rpy),
        gravity=np.asarray(desc.gravity, dtype=float),
    )


def axis_rotation(axis: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations by angles ``q [N]`` about the unit ``axis [3]`` → ``[N,3,3]``."""
    q = np.asarray(q, dtype=float)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s, c = np.sin(q)[:, None, None], np.cos(q)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def _as_batch(q: np.ndarray, n: int) -> tuple[np.ndarray, bool]:
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    q = np.atleast_2d(q)
    if q.shape[1] != n:
        raise ValueError(f"q: expected {n} joint columns, got shape {q.shape}")
    return q, single


def link_poses(desc: RobotDescription | ChainGeometry, q: np.ndarray) -> np.ndarray:
    """World poses of the link frames for each sample: ``[N, n, 4, 4]`` (link i = body moved by joint i)."""
    geo = desc if isinstance(desc, ChainGeometry) else chain_geometry(desc)
    n = geo.axes.shape[0]
    q, _ = _as_batch(q, n)
    out = np.empty((q.shape[0], n, 4, 4))
    cur = np.broadcast_to(geo.world_base, (q.shape[0], 4, 4))
    for i in range(n):  # loop over joints (7), vectorised over samples
        local = np.broadcast_to(geo.joint_origins[i], (q.shape[0], 4, 4)).copy()
        local[:, :3, :3] = local[:, :3, :3] @ axis_rotation(geo.axes[i], q[:, i])
        cur = cur @ local
        out[:, i] = cur
    return out


def flange_pose(desc: RobotDescription | ChainGeometry, q: np.ndarray) -> np.ndarray:
    """World pose of the flange frame: ``[N,4,4]`` (or ``[4,4]`` for a single ``q [n]``)."""
    geo = desc if isinstance(desc, ChainGeometry) else chain_geometry(desc)
    q_b, single = _as_batch(q, geo.axes.shape[0])
    t = link_poses(geo, q_b)[:, -1] @ geo.flange
    return t[0] if single else t


def flange_position(desc: RobotDescription | ChainGeometry, q: np.ndarray) -> np.ndarray:
    """World position of the flange origin [m]: ``[N,3]`` (or ``[3]``)."""
    t = flange_pose(desc, q)
    return t[..., :3, 3]


def point_jacobian(desc: RobotDescription | ChainGeometry, q: np.ndarray,
                   p_flange: np.ndarray | None = None) -> np.ndarray:
    """Geometric Jacobian ``[N, 6, n]`` (angular rows 0–2, translational rows 3–5, world frame) of a point fixed in
    the flange frame at ``p_flange`` [m] (default: the flange origin)."""
    geo = desc if isinstance(desc, ChainGeometry) else chain_geometry(desc)
    q_b, single = _as_batch(q, geo.axes.shape[0])
    poses = link_poses(geo, q_b)
    t_f = poses[:, -1] @ geo.flange
    p = t_f[:, :3, 3]
    if p_flange is not None:
        p = p + t_f[:, :3, :3] @ np.asarray(p_flange, dtype=float)
    # joint axis in world: R_link_i · axis_i (the joint rotation is about its own axis, so child frame works too)
    z = np.einsum("nijk,ik->nij", poses[:, :, :3, :3], geo.axes)        # [N,n,3]
    o = poses[:, :, :3, 3]                                               # [N,n,3]
    jac = np.empty((q_b.shape[0], 6, geo.axes.shape[0]))
    jac[:, :3, :] = np.transpose(z, (0, 2, 1))
    jac[:, 3:, :] = np.transpose(np.cross(z, p[:, None, :] - o), (0, 2, 1))
    return jac[0] if single else jac


def flange_jacobian(desc: RobotDescription | ChainGeometry, q: np.ndarray) -> np.ndarray:
    """Geometric Jacobian of the flange origin, ``[N,6,n]`` (or ``[6,n]``), world frame, [ω; v] row order."""
    return point_jacobian(desc, q)
