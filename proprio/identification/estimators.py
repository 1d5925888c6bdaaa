"""Base-parameter estimators (thesis §4.1): OLS with relative standard deviations (eq. 4.22–4.27), weighted least
squares, and a physically consistent estimate as a semidefinite program in Drake's ``MathematicalProgram``.

All three take joint-space data ``q, qd, qdd, tau [N, n]`` (rad, rad/s, rad/s², N·m) and return an
:class:`~proprio.identification.model_io.IdentifiedModel` (``τ = K_b φ_b`` plus a full standard parameter set).
The normal equations are accumulated from the regressor buffer one joint row-block at a time (``B[i, 12i:]`` is
contiguous), so ``K_b`` is never stacked; the solve is a column-equilibrated Cholesky with one step of iterative
refinement on the explicit residual.

**Extra unknowns** per joint after the base parameters, in this order: a constant torque offset ``τ_0`` [N·m]
(``offsets``) and the load gain ``k`` [-] of load-dependent Coulomb friction (``load_friction``: the column
``sgn_s(q̇_j) |τ_j|`` of :func:`proprio.friction_law.load_coulomb` with the *measured* torque as the load, the link
torque the joint transmits; its no-load level ``F_c0`` is the regressor's Coulomb parameter); then, with
``sensor`` settings (:mod:`proprio.identification.sensor_terms`), the torque sensor's gain error [-] (its column
the a-priori torque ``Y φ_prior``, a weak prior on it settling the common scale), hysteresis and lost motion
(each a level [N·m] and a load gain [-], the a-priori torque's magnitude as the load) and, with gear ratios, its
ripple (sin/cos amplitudes [N·m]): the twin's laws on the measured motion, each recording (``pieces``: the sample
counts of the stacked recordings) from the virgin state at its first sample.

Data checks run before any fit: NaN/inf, too few samples, joints that never move, and a rank-deficient ``K_b``
raise :class:`IdentificationError` naming the base parameters that cannot be identified and why.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg

from proprio import friction_law
from proprio.description import RobotDescription
from proprio.identification.base_parameters import BaseParameters, base_parameters
from proprio.identification.model_io import IdentifiedModel, data_digest
from proprio.identification.regressor import (PARAMS_PER_JOINT, drive_identified, n_parameters, predict,
                                              regressor_buffer, standard_parameters)
from proprio.identification.sensor_terms import GAIN_PRIOR_STD, SENSOR_BOUNDS, SensorTermSettings, sensor_columns

__all__ = ["IdentificationError", "NormalEquations", "normal_equations", "check_data", "ols", "wls", "sdp",
           "identify", "torque_error_table", "METHODS", "MOTION_THRESHOLD", "CONDITION_LIMIT", "GAIN_PRIOR_RESIDUAL"]

METHODS = ("ols", "wls", "sdp")
MOTION_THRESHOLD = 1e-3      # [rad] a joint whose position range is below this never moved
CONDITION_LIMIT = 1e10       # cond(K_b) (columns scaled to unit norm) above this: numerically rank deficient
GAIN_PRIOR_RESIDUAL = 0.01
"""The residual σ the sensor gains' prior is weighed against, as a fraction of each joint's RMS τ [-]: the prior's
precision ``(σ_e / GAIN_PRIOR_STD)²`` needs a residual scale before the fit (the fit's own residual would make it
circular); 1 % of the torque scale is the order of a good backbone's residual, so the prior settles only the direction
the data leave free (a gain common to all joints, the rigid body's overall scale) and does not pull the others."""


class IdentificationError(ValueError):
    """The data cannot identify the base parameters; the message names the unidentifiable ones and why."""


@dataclass
class NormalEquations:
    """``G = K_bᵀ W K_b``, ``b = K_bᵀ W τ`` and what the estimators need to evaluate residuals."""
    gram: np.ndarray          # [r (+n), r (+n)]
    rhs: np.ndarray           # [r (+n)]
    buffer: np.ndarray        # regressor buffer [n, p, N]
    tau: np.ndarray           # [N, n]
    extras: tuple[str, ...]   # the per-joint extra unknowns after the base parameters (module docstring)
    columns: np.ndarray       # [len(extras), N, n] their columns (joint i's column acts in joint i's rows)
    prior_precision: np.ndarray | None = None   # [r (+n)] added to gram's diagonal (the gains' prior; None: none)

    @property
    def offsets(self) -> bool:
        return "offset" in self.extras


def extra_columns(extras: tuple[str, ...], q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                  coulomb_velocity_scale: float | None, sensor: SensorTermSettings | None = None,
                  pieces: Sequence[int] | None = None, prior: np.ndarray | None = None) -> np.ndarray:
    """The columns ``[len(extras), N, n]`` of the extra unknowns (module docstring): ones for ``offset``,
    ``sgn_s(q̇) |τ|`` for ``load_gain``, then the ``sensor`` terms (:func:`sensor_columns` per piece)."""
    cols = {"offset": lambda: np.ones_like(tau),
            "load_gain": lambda: friction_law.load_coulomb(qd, 0.0, 1.0, tau, coulomb_velocity_scale)}
    out = [cols[k]() for k in extras if k in cols]
    if sensor is not None:
        out += list(np.concatenate([sensor_columns(sensor, q[k], qd[k], prior[k])[0]
                                    for k in piece_slices(pieces, tau.shape[0])], axis=1))
    return np.stack(out) if out else np.zeros((0,) + tau.shape)


def piece_slices(pieces: Sequence[int] | None, n_samples: int) -> list[slice]:
    """The slices of stacked recordings in a stack of ``n_samples`` (``pieces``: each recording's sample count;
    ``None``: one recording), checked to cover it: the sensor terms' state restarts at each slice's first sample."""
    ends = np.cumsum([0] + list(pieces or [n_samples]))
    if ends[-1] != n_samples:
        raise ValueError(f"pieces {list(pieces or [])} sum to {ends[-1]} samples, the data have {n_samples}")
    return [slice(int(a), int(b)) for a, b in zip(ends[:-1], ends[1:])]


def _base_columns(base: BaseParameters, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions (in ``φ_b``) and buffer columns (offset from ``12i``) of the base parameters joint ``i`` sees."""
    sel = np.flatnonzero(base.independent >= PARAMS_PER_JOINT * i)
    return sel, base.independent[sel] - PARAMS_PER_JOINT * i


def _extras(offsets: bool, load_friction: bool, sensor: SensorTermSettings | None = None) -> tuple[str, ...]:
    return ((("offset",) if offsets else ()) + (("load_gain",) if load_friction else ())
            + (sensor.terms if sensor is not None else ()))


def normal_equations(desc: RobotDescription, base: BaseParameters, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     tau: np.ndarray, coulomb_velocity_scale: float | None, weights: np.ndarray | None = None,
                     offsets: bool = False, load_friction: bool = False, sensor: SensorTermSettings | None = None,
                     pieces: Sequence[int] | None = None) -> NormalEquations:
    """Accumulate the (weighted, per-joint ``weights [n]``) normal equations of ``τ = K_b φ_b (+ τ_0 + k sgn_s(q̇)|τ|
    + sensor terms)`` (the extra unknowns of the module docstring)."""
    buf = regressor_buffer(desc, q, qd, qdd, coulomb_velocity_scale)
    r, n = base.n_base, desc.n
    extras = _extras(offsets, load_friction, sensor)
    prior = None if sensor is None else predict(buf, standard_parameters(desc))   # the a-priori torque Y φ_prior
    xc = extra_columns(extras, q, qd, tau, coulomb_velocity_scale, sensor, pieces, prior)
    m = r + n * len(extras)
    gram, rhs = np.zeros((m, m)), np.zeros(m)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
    for i in range(n):
        sel, cols = _base_columns(base, i)
        k_i = buf[i, PARAMS_PER_JOINT * i:][cols]          # [r_i, N] rows of K_bᵀ for joint i
        gram[np.ix_(sel, sel)] += w[i] * (k_i @ k_i.T)
        rhs[sel] += w[i] * (k_i @ tau[:, i])
        at = r + n * np.arange(len(extras)) + i             # joint i's extra unknowns
        x_i = xc[:, :, i]                                    # [len(extras), N]: columns in joint i's rows
        gram[np.ix_(sel, at)] = w[i] * (k_i @ x_i.T)
        gram[np.ix_(at, sel)] = gram[np.ix_(sel, at)].T
        gram[np.ix_(at, at)] = w[i] * (x_i @ x_i.T)
        rhs[at] = w[i] * (x_i @ tau[:, i])
    precision = None
    if sensor is not None:      # the gains' prior N(0, σ_g²) against the residual scale σ_e (GAIN_PRIOR_RESIDUAL)
        at = r + n * extras.index("gain") + np.arange(n)
        sigma_e = GAIN_PRIOR_RESIDUAL * np.sqrt(np.mean(tau ** 2, axis=0))
        precision = np.zeros(m)
        precision[at] = w * (sigma_e / GAIN_PRIOR_STD) ** 2
        gram[at, at] += precision[at]
    return NormalEquations(gram, rhs, buf, tau, extras, xc, precision)


def _predict_base(ne: NormalEquations, base: BaseParameters, phi_b: np.ndarray) -> np.ndarray:
    n = ne.buffer.shape[0]
    out = np.empty_like(ne.tau)
    for i in range(n):
        sel, cols = _base_columns(base, i)
        out[:, i] = phi_b[sel] @ ne.buffer[i, PARAMS_PER_JOINT * i:][cols]
    r = base.n_base
    for b in range(len(ne.extras)):
        out += phi_b[r + n * b:r + n * (b + 1)] * ne.columns[b]
    return out


def _kt_times(ne: NormalEquations, base: BaseParameters, resid: np.ndarray, weights: np.ndarray) -> np.ndarray:
    out = np.zeros(ne.rhs.size)
    for i in range(ne.buffer.shape[0]):
        sel, cols = _base_columns(base, i)
        out[sel] += weights[i] * (ne.buffer[i, PARAMS_PER_JOINT * i:][cols] @ resid[:, i])
        for b in range(len(ne.extras)):
            out[base.n_base + ne.buffer.shape[0] * b + i] = weights[i] * (ne.columns[b, :, i] @ resid[:, i])
    return out


def check_data(desc: RobotDescription, base: BaseParameters, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
               tau: np.ndarray, gram: np.ndarray | None = None) -> None:
    """Raise :class:`IdentificationError` for data that cannot identify ``base`` (see the module docstring)."""
    n = desc.n
    for name, arr in (("q", q), ("qd", qd), ("qdd", qdd), ("tau", tau)):
        arr = np.asarray(arr)
        if arr.ndim != 2 or arr.shape[1] != n:
            raise IdentificationError(f"{name} must be [N, {n}], got shape {arr.shape}")
        bad = ~np.isfinite(arr)
        if bad.any():
            s, j = np.argwhere(bad)[0]
            raise IdentificationError(f"{name} contains {int(bad.sum())} NaN/inf values (first at sample {s}, joint "
                                      f"{j + 1}); no parameter can be identified from them — clean or cut the data")
    n_s = q.shape[0]
    if n_s * n < base.n_base:
        raise IdentificationError(f"too short: {n_s} samples × {n} joints = {n_s * n} equations < {base.n_base} base "
                                  f"parameters; all of {', '.join(base.names[:3])}, ... are unidentifiable")
    still = [j for j in range(n) if np.ptp(q[:, j]) < MOTION_THRESHOLD]
    if still:
        hit = [nm for nm, idx in zip(base.names, base.independent) if idx // PARAMS_PER_JOINT in still]
        raise IdentificationError(
            f"joint(s) {', '.join(str(j + 1) for j in still)} never move (position range < {MOTION_THRESHOLD} rad); "
            f"unidentifiable: {', '.join(hit)}")
    if gram is not None:
        names = list(base.names) + [f"extra{j + 1}" for j in range(gram.shape[0] - base.n_base)]
        d = np.sqrt(np.diag(gram))
        if np.any(d <= 1e-10 * d.max()):
            zero = [names[k] for k in np.flatnonzero(d <= 1e-10 * d.max())]
            raise IdentificationError(f"regressor columns are zero (never excited): {', '.join(zero)}")
        g = gram / np.outer(d, d)
        ev, vec = np.linalg.eigh(g)
        cond = np.sqrt(ev[-1] / max(ev[0], 1e-300))
        if cond > CONDITION_LIMIT:
            weak = np.abs(vec[:, ev < ev[-1] / CONDITION_LIMIT ** 2]).max(axis=1)
            hit = [names[k] for k in np.argsort(-weak)[:6] if weak[k] > 0.1]
            raise IdentificationError(
                f"rank-deficient data: cond(K_b) = {cond:.3g} > {CONDITION_LIMIT:.0e}; the data do not separate "
                f"{', '.join(hit)} (too short or not exciting enough — use an optimised excitation trajectory)")


def _solve_spd(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    d = 1.0 / np.sqrt(np.diag(gram))
    c = scipy.linalg.cho_factor(gram * np.outer(d, d))
    return d * scipy.linalg.cho_solve(c, d * rhs)


def _least_squares(ne: NormalEquations, base: BaseParameters, weights: np.ndarray) -> np.ndarray:
    phi_b = _solve_spd(ne.gram, ne.rhs)
    resid = ne.tau - _predict_base(ne, base, phi_b)                     # iterative refinement (one step)
    step = _kt_times(ne, base, resid, weights) - (0.0 if ne.prior_precision is None else ne.prior_precision * phi_b)
    return phi_b + _solve_spd(ne.gram, step)


def _sigma_pct(ne: NormalEquations, base: BaseParameters, phi_b: np.ndarray, weights: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Relative standard deviations [%] (eq. 4.24–4.27) and the residual ``τ − K_b φ_b``."""
    resid = ne.tau - _predict_base(ne, base, phi_b)
    n_eq = resid.size
    var = float(np.sum(weights * resid ** 2)) / max(n_eq - phi_b.size, 1)            # eq. 4.27
    cov = var * np.linalg.inv(ne.gram)                                               # eq. 4.26
    sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None))                                # eq. 4.25
    with np.errstate(divide="ignore"):
        pct = 100.0 * sigma / np.abs(phi_b)                                          # eq. 4.24
    return pct, resid


def _full_set(base: BaseParameters, phi_b: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """The standard set nearest to ``prior`` (Euclidean) with ``K φ = φ_b`` (``φ_b`` without offsets)."""
    k = base.projection
    return prior + k.T @ np.linalg.solve(k @ k.T, phi_b[:base.n_base] - k @ prior)


def _prepare(desc, q, qd, qdd, tau, base, coulomb_velocity_scale, offsets, load_friction=False, sensor=None,
             pieces=None):
    q, qd, qdd, tau = (np.asarray(a, dtype=float) for a in (q, qd, qdd, tau))
    base = base or base_parameters(desc)
    if base.robot != desc.name or base.n_standard != n_parameters(desc):
        raise ValueError(f"base parameters were computed for {base.robot!r}, not for {desc.name!r}")
    if sensor is not None and drive_identified(desc):
        raise ValueError(f"sensor: the robot description {desc.name!r} says τ is a drive torque (drive.tau_kind: "
                         "drive); the sensor terms are a link-side torque sensor's and their a-priori torque has no "
                         "drive terms — leave sensor out")
    check_data(desc, base, q, qd, qdd, tau)
    ne = normal_equations(desc, base, q, qd, qdd, tau, coulomb_velocity_scale, offsets=offsets,
                          load_friction=load_friction, sensor=sensor, pieces=pieces)
    check_data(desc, base, q, qd, qdd, tau, ne.gram)
    return (q, qd, qdd, tau), base, ne


def _model(desc, base, phi_b, pct, phi, method, scale, data, consistent, extras, sensor=None):
    scale = float(friction_law.smoothing(scale))          # the model records the smoothing it was fitted with
    return IdentifiedModel(desc, base, phi_b, pct, phi, method, scale, data_digest(*data), data[0].shape[0],
                           consistent, extras=tuple(extras), sensor=sensor)


def ols(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau: np.ndarray,
        base: BaseParameters | None = None, coulomb_velocity_scale: float | None = None,
        offsets: bool = False, load_friction: bool = False, sensor: SensorTermSettings | None = None,
        pieces: Sequence[int] | None = None) -> IdentifiedModel:
    """Ordinary least squares ``φ_b = (K_bᵀK_b)⁻¹K_bᵀτ`` (eq. 4.22) with σ% (eq. 4.24–4.27).

    ``desc`` gives the kinematics and the a-priori parameters that fill the unidentifiable directions of the full
    set. ``offsets`` adds a constant torque offset per joint [N·m] (a torque-sensor bias, not in the thesis'
    model) as ``n`` extra unknowns after the base parameters; ``load_friction`` the load gain of load-dependent
    Coulomb friction per joint; ``sensor`` the torque sensor's terms with these settings, ``pieces`` the sample
    counts of the recordings stacked in the data (module docstring)."""
    data, base, ne = _prepare(desc, q, qd, qdd, tau, base, coulomb_velocity_scale, offsets, load_friction, sensor,
                              pieces)
    ones = np.ones(desc.n)
    phi_b = _least_squares(ne, base, ones)
    pct, _ = _sigma_pct(ne, base, phi_b, ones)
    phi = _full_set(base, phi_b, standard_parameters(desc))
    return _model(desc, base, phi_b, pct, phi, "ols", coulomb_velocity_scale, data, False, ne.extras, sensor)


def wls(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau: np.ndarray,
        base: BaseParameters | None = None, coulomb_velocity_scale: float | None = None,
        offsets: bool = False, load_friction: bool = False, sensor: SensorTermSettings | None = None,
        pieces: Sequence[int] | None = None) -> IdentifiedModel:
    """Weighted least squares (Gautier): each joint's equations weighted by ``1/σ_i²``, ``σ_i`` the joint's OLS
    residual standard deviation; σ% from the weighted covariance. Arguments as :func:`ols`."""
    data, base, ne = _prepare(desc, q, qd, qdd, tau, base, coulomb_velocity_scale, offsets, load_friction, sensor,
                              pieces)
    ones = np.ones(desc.n)
    resid = ne.tau - _predict_base(ne, base, _least_squares(ne, base, ones))
    dof = max(resid.shape[0] - ne.rhs.size / desc.n, 1.0)
    var = np.sum(resid ** 2, axis=0) / dof
    weights = 1.0 / np.maximum(var, 1e-12 * max(var.max(), 1e-300))
    ne_w = normal_equations(desc, base, *data, coulomb_velocity_scale, weights, offsets, load_friction, sensor,
                            pieces)
    phi_b = _least_squares(ne_w, base, weights)
    pct, _ = _sigma_pct(ne_w, base, phi_b, weights)
    phi = _full_set(base, phi_b, standard_parameters(desc))
    return _model(desc, base, phi_b, pct, phi, "wls", coulomb_velocity_scale, data, False, ne.extras, sensor)


def _pseudo_inertia(phi_link):
    """4×4 pseudo-inertia ``[[½tr(I)·1 − I, h], [hᵀ, m]]`` (linear in the link's 10 parameters)."""
    m, hx, hy, hz, ixx, ixy, ixz, iyy, iyz, izz = phi_link
    half = 0.5 * (ixx + iyy + izz)
    return np.array([[half - ixx, -ixy, -ixz, hx],
                     [-ixy, half - iyy, -iyz, hy],
                     [-ixz, -iyz, half - izz, hz],
                     [hx, hy, hz, m]])


def sdp(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau: np.ndarray,
        base: BaseParameters | None = None, coulomb_velocity_scale: float | None = None, offsets: bool = False,
        regularization: float = 1e-4, min_mass: float = 1e-3, load_friction: bool = False,
        sensor: SensorTermSettings | None = None, pieces: Sequence[int] | None = None) -> IdentifiedModel:
    """Physically consistent least squares as an SDP (pseudo-inertia LMI of Wensing et al. 2018; cf. Stürz 2017).

    ``min ‖R(Kφ − φ̂_b)‖ + λ‖φ − φ_prior‖`` over the full standard set ``φ`` (and the offsets) subject to every
    link's pseudo-inertia ``⪰ 0`` with mass ``≥ min_mass`` [kg], ``F_v, F_c ≥ 0``, the load gains ``≥ 0`` and the
    sensor terms inside the effects' bounds (hysteresis and lost-motion levels ≥ 0, their load gains in ``[0,
    MAX_LOAD_GAIN]``; gain and ripple free). ``R`` is the Cholesky factor of ``K_bᵀK_b`` and ``φ̂_b`` the OLS
    solution, so the first term is the LS residual norm above its minimum; ``λ = regularization · ‖R‖₂`` only picks
    the unidentifiable directions closest to the a-priori ``desc``. Both terms are norms (second-order cones), so when the OLS solution is physically consistent it is an exact
    minimiser of the data term. Solved with Clarabel; then polished onto ``Kφ = φ̂_b`` when that stays consistent.
    """
    from pydrake.solvers import ClarabelSolver, MathematicalProgram

    data, base, ne = _prepare(desc, q, qd, qdd, tau, base, coulomb_velocity_scale, offsets, load_friction, sensor,
                              pieces)
    ones = np.ones(desc.n)
    phi_ls = _least_squares(ne, base, ones)
    prior = standard_parameters(desc)
    r, p, n_x = base.n_base, base.n_standard, ne.rhs.size - base.n_base
    lift = np.zeros((r + n_x, p + n_x))                               # [φ, τ_0] → [φ_b, τ_0]
    lift[:r, :p] = base.projection
    lift[r:, p:] = np.eye(n_x)
    r_chol = scipy.linalg.cholesky(ne.gram)                           # upper: G = RᵀR
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(p + n_x, "phi")
    prog.AddL2NormCostUsingConicConstraint(r_chol @ lift, -r_chol @ phi_ls, x)
    lam = regularization * np.linalg.norm(r_chol, 2)
    prog.AddL2NormCostUsingConicConstraint(lam * np.eye(p), -lam * prior, x[:p])
    for j in range(desc.n):
        blk = x[PARAMS_PER_JOINT * j:PARAMS_PER_JOINT * j + 10]
        prog.AddPositiveSemidefiniteConstraint(_pseudo_inertia(blk))
        prog.AddLinearConstraint(blk[0] >= min_mass)
        prog.AddBoundingBoxConstraint(0.0, np.inf, x[PARAMS_PER_JOINT * j + 10:PARAMS_PER_JOINT * j + 12])
    if p > PARAMS_PER_JOINT * desc.n:                                 # drive: I_a, F_v,m, F_c,m ≥ 0
        prog.AddBoundingBoxConstraint(0.0, np.inf, x[PARAMS_PER_JOINT * desc.n:p])
    bounds = _extra_bounds(ne.extras)
    for k, (lo, hi) in bounds.items():                                # load gains ≥ 0, the sensor terms' bounds
        at = p + desc.n * ne.extras.index(k)
        prog.AddBoundingBoxConstraint(lo, hi, x[at:at + desc.n])
    result = ClarabelSolver().Solve(prog)
    if not result.is_success():
        raise IdentificationError(f"SDP failed ({result.get_solution_result()}); the data may be inconsistent with "
                                  "any physical parameter set")
    sol = result.GetSolution(x)
    phi_val = sol[:p]
    polished = _full_set(base, phi_ls, phi_val)                       # exact LS optimum if it stays feasible
    extra_ls = {k: phi_ls[r + desc.n * ne.extras.index(k):][:desc.n] for k in bounds}
    inside = all(np.all((lo <= extra_ls[k]) & (extra_ls[k] <= hi)) for k, (lo, hi) in bounds.items())
    if _consistent(polished, desc.n, min_mass) and inside:
        phi_val, sol[p:] = polished, phi_ls[r:]
    phi_val = _clip_second_moments(phi_val, desc.n)
    phi_b = np.concatenate([base.to_base(phi_val), sol[p:]])
    pct, _ = _sigma_pct(ne, base, phi_b, ones)
    return _model(desc, base, phi_b, pct, phi_val, "sdp", coulomb_velocity_scale, data, True, ne.extras, sensor)


def _extra_bounds(extras: tuple[str, ...]) -> dict[str, tuple[float, float]]:
    """``(lower, upper)`` of the bounded extras among ``extras``: the friction load gain ``k ≥ 0`` (dissipative) and
    the sensor terms the effects bound (:data:`~proprio.identification.sensor_terms.SENSOR_BOUNDS`)."""
    bounds = {"load_gain": (0.0, np.inf), **SENSOR_BOUNDS}
    return {k: bounds[k] for k in extras if k in bounds}


def _clip_second_moments(phi: np.ndarray, n: int, floor: float = 1e-9) -> np.ndarray:
    """Raise each link's central second-moment eigenvalues to ``floor · trace`` (the interior-point solution may sit
    ~1e-9 outside the cone); changes parameters by ≲ 1e-9 and makes Drake's ``IsPhysicallyValid`` hold strictly."""
    out = phi.copy()
    for j in range(n):
        m, h, i_o = out[12 * j], out[12 * j + 1:12 * j + 4], out[12 * j + 4:12 * j + 10]
        c = h / m
        i_mat = np.array([[i_o[0], i_o[1], i_o[2]], [i_o[1], i_o[3], i_o[4]], [i_o[2], i_o[4], i_o[5]]])
        i_c = i_mat - m * (c @ c * np.eye(3) - np.outer(c, c))
        sig = 0.5 * np.trace(i_c) * np.eye(3) - i_c                       # central second moment Σ_c
        ev, vec = np.linalg.eigh(sig)
        lo = floor * max(np.trace(sig), 1e-12)
        if ev[0] >= lo:
            continue
        sig = vec @ np.diag(np.maximum(ev, lo)) @ vec.T
        i_c = np.trace(sig) * np.eye(3) - sig
        i_mat = i_c + m * (c @ c * np.eye(3) - np.outer(c, c))
        out[12 * j + 4:12 * j + 10] = i_mat[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    return out


def inconsistent_links(model) -> list[int]:
    """The joints (1-based) whose link parameters in ``model.phi`` (the full set an identification implies) are not
    physically consistent: a pseudo-inertia with a negative eigenvalue, no positive mass, or negative friction."""
    return _inconsistent_links(np.asarray(model.phi), model.description.n, np.finfo(float).tiny)


def _inconsistent_links(phi: np.ndarray, n: int, min_mass: float) -> list[int]:
    p = phi[:PARAMS_PER_JOINT * n].reshape(n, PARAMS_PER_JOINT)
    return [j + 1 for j, row in enumerate(p) if not (np.linalg.eigvalsh(_pseudo_inertia(row[:10]))[0] >= 0.0
                                                     and row[0] >= min_mass and row[10] >= 0.0 and row[11] >= 0.0)]


def _consistent(phi: np.ndarray, n: int, min_mass: float) -> bool:
    return bool(np.all(phi[PARAMS_PER_JOINT * n:] >= 0.0) and not _inconsistent_links(phi, n, min_mass))


def identify(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau: np.ndarray,
             method: str = "ols", base: BaseParameters | None = None, coulomb_velocity_scale: float | None = None,
             offsets: bool = False, load_friction: bool = False, sensor: SensorTermSettings | None = None,
             pieces: Sequence[int] | None = None) -> IdentifiedModel:
    """Dispatch to :func:`ols`, :func:`wls` or :func:`sdp` (``load_friction``: fit the load gain of load-dependent
    Coulomb friction; ``sensor``, ``pieces``: the torque sensor's terms, module docstring)."""
    fns = {"ols": ols, "wls": wls, "sdp": sdp}
    if method not in fns:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    return fns[method](desc, q, qd, qdd, tau, base=base, coulomb_velocity_scale=coulomb_velocity_scale,
                       offsets=offsets, load_friction=load_friction, sensor=sensor, pieces=pieces)


def torque_error_table(tau_meas: np.ndarray, tau_pred: np.ndarray, title: str = "") -> tuple[str, dict]:
    """Per-joint error statistics in the layout of thesis Table 4.4: MSE [N²·m²], σ of the error [N·m], and
    RMSE [N·m]; plus the mean over samples of ‖e‖₂ across joints [N·m] (FloBaRoID's "absolute" figure)."""
    e = np.asarray(tau_meas) - np.asarray(tau_pred)
    mse = np.mean(e ** 2, axis=0)
    sd = np.std(e, axis=0)
    rmse = np.sqrt(mse)
    lines = [title] if title else []
    lines.append(f"{'joint':>7} {'MSE [N·m²]':>11} {'sigma [N·m]':>11} {'RMSE [N·m]':>10}")
    for j, (a, b, c) in enumerate(zip(mse, sd, rmse)):
        lines.append(f"{j + 1:>7} {a:>11.4f} {b:>11.4f} {c:>10.4f}")
    lines.append(f"{'average':>7} {mse.mean():>11.4f} {sd.mean():>11.4f} {rmse.mean():>10.4f}")
    norm = float(np.mean(np.linalg.norm(e, axis=1)))
    lines.append(f"mean ||e||_2 over samples: {norm:.4f} N·m")
    return "\n".join(lines), {"mse": mse, "sigma": sd, "rmse": rmse, "mean_norm": norm}
