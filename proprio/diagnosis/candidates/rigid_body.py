"""The rigid-body candidates of the torque gap: an error of the links' inertial parameters and an unmodelled payload
at the flange (a confusable pair: the same regressor columns of the last link)."""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy import linalg

from proprio.description import RobotDescription
from proprio.diagnosis.candidates.base import Candidate, _kept_signals
from proprio.diagnosis.data import GapData
from proprio.dynamics import inverse_dynamics
from proprio.identification.regressor import PARAMS_PER_JOINT, n_parameters, parameter_names, regressor

__all__ = ["RigidBodyCandidate", "PayloadCandidate"]


def _inertial_columns(robot: RobotDescription) -> np.ndarray:
    """Mask of the link-inertial columns of ``robot``'s regressor (not its friction, nor a drive arm's drive
    columns)."""
    k = np.arange(n_parameters(robot))
    return (k < PARAMS_PER_JOINT * robot.n) & (k % PARAMS_PER_JOINT < 10)


class RigidBodyCandidate(Candidate):
    """Error of the rigid-body (inertial) parameters: the identifiable combinations kept by a rank-revealing QR of
    the training regressor (friction columns excluded: friction is its own candidate)."""
    name = "rigid_body"
    place = "link"

    def __init__(self, robot: RobotDescription, train: GapData, rank_tol: float = 1e-6):
        self.robot = robot
        full = self._inertial(train)
        a = full.reshape(-1, full.shape[-1])
        norms = np.linalg.norm(a, axis=0)
        nz = np.flatnonzero(norms > 1e-9 * norms.max())
        _, r, piv = linalg.qr(a[:, nz] / norms[nz], mode="economic", pivoting=True)
        d = np.abs(np.diag(r))
        rank = int((d > rank_tol * d[0]).sum())
        self.columns = np.sort(nz[piv[:rank]])
        names = [nm for k, nm in enumerate(parameter_names(robot.n)) if k % PARAMS_PER_JOINT < 10]
        self._names = [f"δ{names[c]}" for c in self.columns]
        train.cache[("design", self.design_key)] = full[..., self.columns]
        # the training motion, for mapping a fit back to physical link inertials (:meth:`patch`)
        self._motion = tuple(train.stack([getattr(s, k) for s in train.signals]) for k in ("q", "qd", "qdd"))

    @classmethod
    def of(cls, robot: RobotDescription, train: GapData) -> "RigidBodyCandidate":
        """The candidate for ``train``, built once per training set (its rank-revealing QR is the costly part)."""
        key = ("candidate", cls.name)
        if key not in train.cache:
            train.cache[key] = cls(robot, train)
        return train.cache[key]

    def _inertial(self, data: GapData) -> np.ndarray:
        keep = _inertial_columns(self.robot)
        return np.concatenate([regressor(self.robot, s.q, s.qd, s.qdd)[..., keep] for s in _kept_signals(data)])

    def param_names(self) -> list[str]:
        return self._names

    def design(self, data: GapData) -> np.ndarray:
        return self._inertial(data)[..., self.columns]

    def patch(self, theta: np.ndarray) -> dict[str, Any] | None:
        """``{"robot": <corrected description mapping>}``: the fit corrects only identifiable combinations, so the
        torque it predicts on the training motion, ``Y (φ_nominal + δφ)``, is identified again with the physically
        consistent SDP (:func:`proprio.identification.estimators.sdp`: pseudo-inertia ⪰ 0, unidentifiable
        directions nearest the nominal model) and rebuilt as link inertials (friction kept as it was)."""
        from proprio.identification.estimators import IdentificationError, sdp
        from proprio.identification.regressor import parameters_to_links, standard_parameters

        robot = self.robot.without_friction()
        keep = _inertial_columns(robot)
        phi = standard_parameters(robot)[keep]
        phi[self.columns] += np.asarray(theta, dtype=float)
        q, qd, qdd = self._motion
        y = regressor(robot, q, qd, qdd)[..., keep]
        target = y @ phi
        try:
            model = sdp(robot, q, qd, qdd, target)
            links = parameters_to_links(model.phi, robot)
        except (IdentificationError, ValueError) as exc:
            self.patch_note = (f"rigid_body: not patched — no physically consistent inertials fit the correction "
                               f"({exc})")
            return None
        new = self.robot.with_inertials(links)
        miss = float(np.sqrt(np.mean((inverse_dynamics(new.without_friction(), q, qd, qdd) - target) ** 2)))
        corr = float(np.sqrt(np.mean((target - y @ standard_parameters(robot)[keep]) ** 2)))
        self.patch_note = (f"rigid_body: the fitted identifiable combinations ({len(self.columns)}) mapped back to "
                           f"physically consistent link inertials by the SDP of proprio.identification.estimators on "
                           f"the training motion ({len(q)} samples); the rebuilt robot's torque differs from the "
                           f"fitted correction by {miss:.3g} N·m RMS (the correction itself: {corr:.3g} N·m RMS)")
        desc = new.to_dict()
        desc["name"] = self.robot.name
        desc["provenance"] = (f"{self.robot.provenance} | inertials corrected by proprio diagnose (rigid_body step, "
                              "SDP-consistent)").strip(" |")
        return {"robot": desc}


class PayloadCandidate(Candidate):
    """An unmodelled payload at the flange: mass ``m`` [kg], first moment ``m·c`` [kg·m] (``c`` in the flange
    frame) and rotational inertia about the last link's origin (6 entries, link axes; a point mass off the axis has
    one). Its torque is the last link's 10 regressor columns with the first moment moved to the flange frame —
    the same columns a rigid-body error of the last link has, which is why payload and inertial error are a
    confusable pair (reported as tied when the data cannot separate them)."""
    name = "payload"
    place = "link"

    def __init__(self, robot: RobotDescription):
        from proprio.description import rpy_to_matrix
        self.robot = robot
        self.p_f = np.asarray(robot.end_effector.xyz, dtype=float)
        self.r_f = rpy_to_matrix(robot.end_effector.rpy)

    def param_names(self) -> list[str]:
        return ["mass", "m·cx", "m·cy", "m·cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.full(10, -np.inf)
        lo[0] = 0.0                                        # a payload has no negative mass
        return lo, np.full(10, np.inf)

    def patch(self, theta: np.ndarray) -> dict[str, Any] | None:
        """``{"payload": {mass, com_flange, inertia}}``: mass [kg], CoM [m] and inertia about the CoM [kg·m²] in
        flange axes, from the fitted mass, first moment and inertia about the last link's origin (parallel axes);
        an indefinite inertia is projected onto the nearest positive semi-definite one (said in ``patch_note``)."""
        theta = np.asarray(theta, dtype=float)
        m = float(theta[0])
        if not m > 0.0:
            self.patch_note = f"payload: not patched — fitted mass {m:.3g} kg is not positive"
            return None
        c = theta[1:4] / m                                            # CoM in flange axes
        p = self.p_f + self.r_f @ c                                   # CoM in the last link's frame
        ixx, ixy, ixz, iyy, iyz, izz = theta[4:10]
        i_o = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        i_c = self.r_f.T @ (i_o - m * (p @ p * np.eye(3) - np.outer(p, p))) @ self.r_f
        ev, vec = np.linalg.eigh(0.5 * np.trace(i_c) * np.eye(3) - i_c)        # central second moment ⪰ 0
        self.patch_note = ""
        if ev[0] < 0.0:
            sig = vec @ np.diag(np.maximum(ev, 0.0)) @ vec.T
            i_c = np.trace(sig) * np.eye(3) - sig
            self.patch_note = (f"payload: the fitted inertia about the CoM was not physical (second-moment eigenvalue "
                               f"{ev[0]:.3g} kg·m²); projected onto the nearest physical one")
        return {"payload": {"mass": m, "com_flange": c.tolist(),
                            "inertia": [float(i_c[a, b]) for a, b in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))]}}

    def design(self, data: GapData) -> np.ndarray:
        n = self.robot.n
        c0 = PARAMS_PER_JOINT * (n - 1)
        out = []
        for s in _kept_signals(data):
            y = regressor(self.robot, s.q, s.qd, s.qdd)[..., c0:c0 + 10]
            out.append(np.concatenate([y[..., :1] + y[..., 1:4] @ self.p_f[:, None], y[..., 1:4] @ self.r_f,
                                       y[..., 4:10]], axis=-1))
        return np.concatenate(out)
