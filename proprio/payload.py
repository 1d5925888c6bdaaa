"""A payload rigidly attached at the flange, and its composition into the last link's inertials."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from proprio.description import INERTIA_KEYS, DescriptionError, Link, RobotDescription, rpy_to_matrix
from proprio.typed_yaml import load_typed

__all__ = ["Payload", "PayloadBlock", "attach_payload"]


@dataclass(frozen=True)
class Payload:
    """A rigid payload: ``mass`` [kg], CoM ``com_flange`` [m] in the flange frame, rotational inertia about its CoM
    ``inertia`` = (ixx, iyy, izz, ixy, ixz, iyz) [kg·m²] in flange axes (default: a point mass)."""
    mass: float
    com_flange: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not np.isfinite(self.mass) or self.mass < 0:
            raise DescriptionError(f"payload.mass must be a finite number >= 0 kg, got {self.mass}")
        if len(self.com_flange) != 3 or not np.all(np.isfinite(self.com_flange)):
            raise DescriptionError(f"payload.com_flange must be 3 finite numbers [m], got {self.com_flange}")
        if len(self.inertia) != 6 or not np.all(np.isfinite(self.inertia)):
            raise DescriptionError(f"payload.inertia must be 6 finite numbers (ixx, iyy, izz, ixy, ixz, iyz) [kg m^2], "
                                   f"got {self.inertia}")
        ixx, iyy, izz, ixy, ixz, iyz = self.inertia
        if np.linalg.eigvalsh(np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))[0] < -1e-12:
            raise DescriptionError(f"payload.inertia is not positive semi-definite: {self.inertia}")

    @classmethod
    def from_dict(cls, d: dict | None, where: str = "payload") -> "Payload | None":
        """Parse a YAML block ``{mass, com_flange, inertia}`` strictly (:mod:`proprio.typed_yaml`: an unknown key
        names the nearest one, a word or a wrong-length list names the field); ``None`` or mass 0 gives ``None``.
        ``inertia`` is 6 numbers or a mapping ``{ixx, iyy, izz, ixy, ixz, iyz}``."""
        block = load_typed(PayloadBlock, d, where, DescriptionError)
        if block.mass == 0.0:
            return None
        inertia = block.inertia
        if isinstance(inertia, InertiaBlock):
            inertia = tuple(getattr(inertia, k) for k in INERTIA_KEYS)
        return cls(block.mass, block.com_flange, inertia)


@dataclass(frozen=True)
class InertiaBlock:
    """The mapping form of a payload's ``inertia`` [kg·m²], about its CoM in flange axes."""
    ixx: float = 0.0
    iyy: float = 0.0
    izz: float = 0.0
    ixy: float = 0.0
    ixz: float = 0.0
    iyz: float = 0.0


@dataclass(frozen=True)
class PayloadBlock:
    """The YAML schema of a ``payload:`` block (twin config, twin patch): ``mass`` [kg], ``com_flange`` [m],
    ``inertia`` [kg·m²] (6 numbers or an :class:`InertiaBlock`)."""
    mass: float = 0.0
    com_flange: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia: tuple[float, float, float, float, float, float] | InertiaBlock = (0.0,) * 6


def attach_payload(desc: RobotDescription, payload: Payload | None) -> RobotDescription:
    """Fold ``payload`` into the last link's mass, CoM and inertia (parallel-axis theorem); exact for rigid-body
    dynamics. Returns ``desc`` unchanged when there is no payload."""
    if payload is None or payload.mass == 0.0:
        return desc
    last = desc.links[-1]
    ee = desc.end_effector
    r_fl = rpy_to_matrix(ee.rpy)
    p_c = np.asarray(ee.xyz) + r_fl @ np.asarray(payload.com_flange)    # payload CoM in the last link frame
    ixx, iyy, izz, ixy, ixz, iyz = payload.inertia
    i_p = r_fl @ np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]) @ r_fl.T
    m1, c1, i1 = last.mass, np.asarray(last.com_xyz), last.inertia_matrix_link()
    m = m1 + payload.mass
    c = (m1 * c1 + payload.mass * p_c) / m

    def shift(i_c: np.ndarray, mass: float, d: np.ndarray) -> np.ndarray:
        return i_c + mass * (d @ d * np.eye(3) - np.outer(d, d))

    i_tot = shift(i1, m1, c1 - c) + shift(i_p, payload.mass, p_c - c)
    new_last = Link(name=last.name, mass=m, com_xyz=tuple(c), com_rpy=(0.0, 0.0, 0.0),
                    inertia_com=(i_tot[0, 0], i_tot[1, 1], i_tot[2, 2], i_tot[0, 1], i_tot[0, 2], i_tot[1, 2]),
                    collision=last.collision)
    return dataclasses.replace(desc, links=desc.links[:-1] + (new_last,))
