"""Base (identifiable) parameters by rank-revealing QR of a random-sample regressor (thesis §4.1, eq. 4.5–4.8).

With ``Y`` the stacked regressor of many random states and ``Y P = Q [R1 R2]`` its column-pivoted QR, the first
``r`` pivoted columns are independent and the rest are combinations of them: ``Y_2 = Y_1 β`` with
``β = R1⁻¹ R2``. Hence ``τ = Y φ = Y_1 (φ_1 + β φ_2) = K_b φ_b`` with base parameters ``φ_b = φ_1 + β φ_2``.

Rank threshold: a pivoted column counts as independent while ``|R_kk| > RANK_TOL · |R_00|`` after the columns have
been scaled to unit norm (so that kg and kg·m² columns compete fairly). ``RANK_TOL = 1e-8`` sits between the
≈1e-13 of exact geometric dependencies and the ≳1e-4 of weakly excited but real ones for random states over the
joint ranges. Columns whose norm is below ``ZERO_TOL = 1e-10`` of the largest are round-off of a structural zero
(e.g. a mass moment along a joint axis that passes through the base axis) and are zeroed before scaling. Coefficients of ``β`` below ``NAME_TOL`` are dropped from the symbolic names only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from proprio.description import RobotDescription
from proprio.identification.regressor import PARAMS_PER_JOINT, drive_identified, parameter_names, regressor

__all__ = ["BaseParameters", "base_parameters", "RANK_TOL", "NAME_TOL"]

RANK_TOL = 1e-8
ZERO_TOL = 1e-10
NAME_TOL = 1e-9


@dataclass(frozen=True)
class BaseParameters:
    """The map between standard parameters ``φ [p]`` and base parameters ``φ_b [r]`` of one robot.

    ``independent``: indices of the standard parameters that keep their own column (``K_b = Y[..., independent]``);
    ``dependent``: the others; ``beta [r, p−r]``: ``φ_b = φ[independent] + β φ[dependent]``.
    """
    robot: str
    independent: np.ndarray
    dependent: np.ndarray
    beta: np.ndarray
    standard_names: tuple[str, ...]
    names: tuple[str, ...]

    @property
    def n_base(self) -> int:
        return int(self.independent.size)

    @property
    def n_standard(self) -> int:
        return len(self.standard_names)

    @property
    def projection(self) -> np.ndarray:
        """``K [r, p]`` with ``φ_b = K φ``."""
        k = np.zeros((self.n_base, self.n_standard))
        k[np.arange(self.n_base), self.independent] = 1.0
        k[:, self.dependent] = self.beta
        return k

    def to_base(self, phi: np.ndarray) -> np.ndarray:
        """``φ_b = φ_1 + β φ_2`` (works on ``[p]`` or ``[..., p]``)."""
        phi = np.asarray(phi, dtype=float)
        return phi[..., self.independent] + phi[..., self.dependent] @ self.beta.T

    def unidentifiable(self) -> list[str]:
        """Standard parameters that never appear alone (they only enter through base-parameter combinations or
        not at all)."""
        return [self.standard_names[i] for i in self.dependent]


def _name(standard: tuple[str, ...], lead: int, coeffs: np.ndarray, dependent: np.ndarray) -> str:
    terms = [standard[lead]]
    for c, d in zip(coeffs, dependent):
        if abs(c) > NAME_TOL:
            terms.append(f"{'+' if c > 0 else '-'} {abs(c):.4g} {standard[d]}" if abs(abs(c) - 1) > 1e-9
                         else f"{'+' if c > 0 else '-'} {standard[d]}")
    return " ".join(terms)


def base_parameters(desc: RobotDescription, n_samples: int = 400, seed: int = 0,
                    with_friction: bool = True) -> BaseParameters:
    """Base parameters of ``desc`` from the QR of the regressor at ``n_samples`` random states (positions uniform
    in the joint limits, velocities and accelerations standard normal in rad/s, rad/s²).

    ``with_friction=False`` drops the joint friction columns (they are then never identifiable). A drive-torque arm
    (``desc.drive.tau_kind == 'drive'``) has the drive columns too (rotor inertia, motor friction on the coupled
    motor velocity): those that duplicate a link's column merge with it (``Izz1 + Ia1``, ``Fv2 + Fvm2``), the coupled
    motor's stay on their own (the TX40's ``Fvm6``)."""
    rng = np.random.default_rng(seed)
    n = desc.n
    q = rng.uniform(desc.lower, desc.upper, size=(n_samples, n))
    qd, qdd = rng.normal(size=(n_samples, n)), rng.normal(size=(n_samples, n))
    y = np.ascontiguousarray(regressor(desc, q, qd, qdd)).reshape(n_samples * n, -1)
    if not with_friction:
        y[:, 10:PARAMS_PER_JOINT * n:PARAMS_PER_JOINT] = 0.0
        y[:, 11:PARAMS_PER_JOINT * n:PARAMS_PER_JOINT] = 0.0
    norms = np.linalg.norm(y, axis=0)
    y[:, norms < ZERO_TOL * norms.max()] = 0.0            # round-off columns (e.g. 1e-14) are structural zeros
    scale = np.where(norms >= ZERO_TOL * norms.max(), norms, 1.0)
    _, r, perm = scipy.linalg.qr(y / scale, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    rank = int(np.sum(diag > RANK_TOL * diag[0]))
    independent, dependent = perm[:rank], perm[rank:]
    # β in unscaled units: Y_2 = Y_1 β  ⇔  (Y_2/s_2) = (Y_1/s_1) R1⁻¹R2  ⇒  β = diag(1/s_1) R1⁻¹ R2 diag(s_2)
    beta_scaled = scipy.linalg.solve_triangular(r[:rank, :rank], r[:rank, rank:])
    beta = beta_scaled / scale[independent][:, None] * scale[dependent][None, :]
    beta[np.abs(beta) < 1e-12] = 0.0
    order = np.argsort(independent)                      # keep the natural (link-by-link) order
    independent, beta = independent[order], beta[order]
    std = tuple(parameter_names(n, drive_identified(desc)))
    names = tuple(_name(std, i, row, dependent) for i, row in zip(independent, beta))
    return BaseParameters(desc.name, independent, dependent, beta, std, names)
