"""Optimal excitation trajectories (thesis §4.1, eq. 4.9–4.19) designed with Drake's ``MathematicalProgram``.

Each joint follows a finite Fourier series (Swevers 1997) with ``L`` harmonics of ``ω_f``::

    q_i(t)  = Σ_l a_il/(ω_f l) sin(ω_f l t) − b_il/(ω_f l) cos(ω_f l t)        (4.9)
    q̇_i(t)  = Σ_l a_il cos(ω_f l t) + b_il sin(ω_f l t)                          (4.10)
    q̈_i(t)  = Σ_l −a_il ω_f l sin(ω_f l t) + b_il ω_f l cos(ω_f l t)             (4.11, sign typo fixed)

The decision variables are the ``2nL`` coefficients. Constraints (all linear in them): ``q(0) = q̇(0) = q̈(0) = 0``
(4.14), and instead of the conservative amplitude bounds (4.15–4.18) the position limits (tightened by the 2°
margin) and the velocity limits imposed exactly at ``constraint_samples`` instants of the period. The cost is
``cond(K_b)`` (4.12) of the base regressor on ``cost_samples`` instants; its gradient is analytic in the SVD
(``∂σ = uᵀ ∂K v``) with ``∂K/∂q_j, ∂K/∂q̇_j, ∂K/∂q̈_j`` from forward differences of the regressor, so one cost
gradient costs one batched regressor call. SNOPT (or IPOPT) runs from several seeded random starts.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

import numpy as np

from proprio.collision import CollisionChecker
from proprio.description import RobotDescription
from proprio.identification.base_parameters import BaseParameters, base_parameters
from proprio.identification.regressor import regressor_buffer, regressor_geometry
from proprio.typed_yaml import ConfigError, check_keys, load_typed, read_yaml

__all__ = ["FourierTrajectory", "ExcitationResult", "ExcitationConfig", "load_excitation_config", "condition_number",
           "optimise_excitation", "check_collisions", "protocol_trajectory", "load_shipped_excitation",
           "protocol_piecewise"]


@dataclass(frozen=True)
class FourierSettings:
    """``fourier:`` — ``harmonics`` L and base frequency ``omega_f`` [rad/s] of eq. (4.9)."""
    harmonics: int = 5
    omega_f: float = 0.1 * math.pi


@dataclass(frozen=True)
class LimitSettings:
    """``limits:`` — position limits tightened by ``position_margin_deg`` [°] on both sides; ``velocity_fraction``
    of the description's velocity limits."""
    position_margin_deg: float = 2.0
    velocity_fraction: float = 1.0


@dataclass(frozen=True)
class OptimisationSettings:
    """``optimisation:`` — ``solver`` (snopt | ipopt), multi-``starts``, ``seed``, ``cost_samples`` and
    ``constraint_samples`` per period, ``initial_amplitude`` [rad/s], ``max_iterations``. The cost's Coulomb columns
    take the one friction law's smoothing (:data:`proprio.friction_law.SMOOTH_VELOCITY`): differentiable, and the
    law the identification fits."""
    solver: str = "snopt"
    starts: int = 4
    seed: int = 0
    cost_samples: int = 100
    constraint_samples: int = 400
    initial_amplitude: float = 0.3
    max_iterations: int = 300


@dataclass(frozen=True)
class CollisionSettings:
    """``collision:`` — ``check_rate_hz`` [Hz] at which the optimised period is checked for self-collision."""
    check_rate_hz: float = 50.0


@dataclass(frozen=True)
class ProtocolSettings:
    """``protocol:`` — the period played once per speed factor, ``repetitions`` times, sampled at ``rate_hz``."""
    speed_factors: tuple[float, ...] = (1.0, 0.8, 0.65, 0.5, 0.4, 0.33, 0.28, 0.25, 0.22)
    repetitions: int = 10
    rate_hz: float = 150.0


@dataclass(frozen=True)
class ExcitationConfig:
    """The excitation design config (``proprio/configs/excitation.yaml``), loaded strictly (:mod:`proprio.typed_yaml`:
    an unknown key names the nearest valid one)."""
    fourier: FourierSettings = FourierSettings()
    limits: LimitSettings = LimitSettings()
    optimisation: OptimisationSettings = OptimisationSettings()
    collision: CollisionSettings = CollisionSettings()
    protocol: ProtocolSettings = ProtocolSettings()

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (for a result's metadata)."""
        return dataclasses.asdict(self)


def load_excitation_config(overrides: dict[str, Any] | None = None) -> ExcitationConfig:
    """The packaged ``excitation.yaml`` with optional section-wise ``overrides`` (``{section: {key: value}}``, checked
    like the file); an unknown section or key is an error naming it and the nearest valid one."""
    source = "excitation.yaml"
    cfg = read_yaml(text=resources.files("proprio.configs").joinpath(source).read_text(), source=source)
    if not isinstance(cfg, dict):
        raise ConfigError(f"{source}: expected a mapping of sections")
    overrides = overrides or {}
    check_keys(overrides, [f.name for f in dataclasses.fields(ExcitationConfig)], "excitation overrides")
    merged = {**cfg}
    for section, values in overrides.items():
        merged[section] = {**(cfg.get(section) or {}), **values}
    config = load_typed(ExcitationConfig, merged, source)
    if config.optimisation.solver not in ("snopt", "ipopt"):
        raise ConfigError(f"{source}: optimisation.solver must be snopt or ipopt, got {config.optimisation.solver!r}")
    return config


@dataclass(frozen=True)
class ShippedExcitation:
    """The schema of a shipped optimal excitation (``proprio/configs/<name>.yaml``): coefficients ``a, b [n][L]``
    [rad/s], ``omega_f`` [rad/s] and provenance."""
    a: list[list[float]]
    b: list[list[float]]
    omega_f: float
    name: str = ""
    provenance: str = ""
    robot: str = ""
    cond: float = math.nan


@dataclass(frozen=True)
class FourierTrajectory:
    """Coefficients ``a, b [n, L]`` [rad/s] and base frequency ``omega_f`` [rad/s] of eq. (4.9)."""
    a: np.ndarray
    b: np.ndarray
    omega_f: float

    @property
    def period(self) -> float:
        return 2.0 * math.pi / self.omega_f

    def basis(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``∂q/∂a, ∂q/∂b, ∂q̇/∂a, ∂q̇/∂b, ∂q̈/∂a, ∂q̈/∂b``, each ``[T, L]``."""
        wl = self.omega_f * np.arange(1, self.a.shape[1] + 1)
        s, c = np.sin(np.outer(t, wl)), np.cos(np.outer(t, wl))
        return s / wl, -c / wl, c, s, -s * wl, c * wl

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``q, qd, qdd [T, n]`` at times ``t [T]`` s."""
        qa, qb, va, vb, aa, ab = self.basis(np.asarray(t, dtype=float))
        return qa @ self.a.T + qb @ self.b.T, va @ self.a.T + vb @ self.b.T, aa @ self.a.T + ab @ self.b.T


def condition_number(desc: RobotDescription, base: BaseParameters, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
                     ) -> float:
    """``cond(K_b)`` of the stacked base regressor at the samples (unscaled columns, as in eq. 4.12; the Coulomb
    columns with the friction law's smoothing, as the optimiser's cost)."""
    buf = regressor_buffer(desc, q, qd, qdd)
    k_b = buf[:, base.independent, :].transpose(2, 0, 1).reshape(-1, base.n_base)
    return float(np.linalg.cond(k_b))


class _CondCost:
    """cond(K_b(a, b)) and its gradient (see the module docstring)."""

    def __init__(self, desc: RobotDescription, base: BaseParameters, t: np.ndarray, harmonics: int,
                 omega_f: float):
        self.desc, self.base, self.t, self.L, self.w = desc, base, t, harmonics, omega_f
        self.geo = regressor_geometry(desc)
        self.basis = FourierTrajectory(np.zeros((desc.n, harmonics)), np.zeros((desc.n, harmonics)),
                                       omega_f).basis(t)

    def _traj(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n, L = self.desc.n, self.L
        return FourierTrajectory(x[:n * L].reshape(n, L), x[n * L:].reshape(n, L), self.w).evaluate(self.t)

    def _kb(self, q, qd, qdd) -> np.ndarray:
        buf = regressor_buffer(self.desc, q, qd, qdd, None, self.geo)
        return buf[:, self.base.independent, :].transpose(2, 0, 1)          # [T, n, r]

    def value_and_gradient(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        n, T = self.desc.n, self.t.size
        q, qd, qdd = self._traj(x)
        k = self._kb(q, qd, qdd)
        u, s, vt = np.linalg.svd(k.reshape(T * n, -1), full_matrices=False)
        cond = s[0] / s[-1]
        # forward differences of K_b along each joint's q, q̇, q̈ (exact for q̈: K is linear in it) — one batched
        # regressor call
        h = 1e-7
        states = [q, qd, qdd]
        batch = []
        for kind in range(3):
            for j in range(n):
                st = [x_.copy() for x_ in states]
                st[kind][:, j] += h
                batch.append(st)
        big = self._kb(*(np.concatenate([b[kind] for b in batch]) for kind in range(3)))
        dk = (big.reshape(3, n, T, n, -1) - k) / h                           # [3, n_joint, T, n, r]
        u1, ur = u[:, 0].reshape(T, n), u[:, -1].reshape(T, n)
        g1 = np.einsum("kjtir,ti,r->kjt", dk, u1, vt[0])                   # ∂σ_max along each state channel
        gr = np.einsum("kjtir,ti,r->kjt", dk, ur, vt[-1])                  # ∂σ_min
        gk = (g1 - cond * gr) / s[-1]                                       # [3, n, T]
        qa, qb, va, vb, aa, ab = self.basis
        grad_a = gk[0] @ qa + gk[1] @ va + gk[2] @ aa                       # [n, L]
        grad_b = gk[0] @ qb + gk[1] @ vb + gk[2] @ ab
        return float(cond), np.concatenate([grad_a.ravel(), grad_b.ravel()])


@dataclass
class ExcitationResult:
    """The best trajectory found, its ``cond(K_b)`` and the cond reached from every start."""
    trajectory: FourierTrajectory
    cond: float
    start_conds: list[float] = field(default_factory=list)
    solver: str = ""


def optimise_excitation(desc: RobotDescription, config: ExcitationConfig | None = None,
                        base: BaseParameters | None = None, progress: bool = False) -> ExcitationResult:
    """Minimise ``cond(K_b)`` over the Fourier coefficients (eq. 4.12–4.19) from ``optimisation.starts`` seeded
    random starts; returns the best feasible result."""
    from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue
    from pydrake.solvers import IpoptSolver, MathematicalProgram, SnoptSolver, SolverOptions

    cfg = config or load_excitation_config()
    fo, li, op = cfg.fourier, cfg.limits, cfg.optimisation
    n, L, w = desc.n, fo.harmonics, fo.omega_f
    base = base or base_parameters(desc)
    period = 2 * math.pi / w
    t_cost = np.linspace(0.0, period, op.cost_samples, endpoint=False)
    cost = _CondCost(desc, base, t_cost, L, w)
    t_con = np.linspace(0.0, period, op.constraint_samples, endpoint=False)
    qa, qb, va, vb, _, _ = FourierTrajectory(np.zeros((n, L)), np.zeros((n, L)), w).basis(t_con)
    qa0, qb0, va0, vb0, aa0, ab0 = FourierTrajectory(np.zeros((n, L)), np.zeros((n, L)), w).basis(np.zeros(1))
    margin = math.radians(li.position_margin_deg)
    lo, hi = desc.lower + margin, desc.upper - margin
    if np.any(lo >= 0) or np.any(hi <= 0):
        raise ValueError("excitation: the zero start configuration must lie strictly inside the tightened limits")
    vmax = desc.velocity_limits * li.velocity_fraction

    solver = SnoptSolver() if op.solver == "snopt" else IpoptSolver()
    if not solver.available():
        solver = IpoptSolver()
    options = SolverOptions()
    if solver.solver_id() == SnoptSolver.id():
        options.SetOption(SnoptSolver.id(), "Major iterations limit", op.max_iterations)
    else:
        options.SetOption(IpoptSolver.id(), "max_iter", op.max_iterations)

    def cost_fn(x):
        if x.dtype == object:
            val, grad = cost.value_and_gradient(ExtractValue(x).ravel())
            return AutoDiffXd(val, grad @ ExtractGradient(x))
        return cost.value_and_gradient(np.asarray(x, dtype=float))[0]

    rng = np.random.default_rng(op.seed)
    best: ExcitationResult | None = None
    conds = []
    starts = range(op.starts)
    if progress:
        from proprio.progress import progress_bar
        starts = progress_bar(starts, desc="excitation starts", unit="start")
    for _ in starts:
        prog = MathematicalProgram()
        a = prog.NewContinuousVariables(n, L, "a")
        b = prog.NewContinuousVariables(n, L, "b")
        for j in range(n):
            x_j = np.concatenate([a[j], b[j]])
            for row_a, row_b in ((qa0[0], qb0[0]), (va0[0], vb0[0]), (aa0[0], ab0[0])):   # eq. 4.14
                prog.AddLinearEqualityConstraint(np.concatenate([row_a, row_b])[None], [0.0], x_j)
            prog.AddLinearConstraint(np.hstack([qa, qb]), np.full(t_con.size, lo[j]), np.full(t_con.size, hi[j]),
                                     x_j)
            prog.AddLinearConstraint(np.hstack([va, vb]), np.full(t_con.size, -vmax[j]),
                                     np.full(t_con.size, vmax[j]), x_j)
        x_all = np.concatenate([a.ravel(), b.ravel()])
        prog.AddCost(cost_fn, vars=x_all)
        x0 = _feasible_start(rng, op.initial_amplitude, n, L, (qa0, qb0, va0, vb0, aa0, ab0),
                             (qa, qb, va, vb), lo, hi, vmax)
        result = solver.Solve(prog, x0, options)
        x = result.GetSolution(x_all)
        traj = _into_limits(FourierTrajectory(x[:n * L].reshape(n, L), x[n * L:].reshape(n, L), w), lo, hi, vmax)
        x = np.concatenate([traj.a.ravel(), traj.b.ravel()])
        feasible = _feasible(traj, lo, hi, vmax)
        c = cost.value_and_gradient(x)[0] if feasible else math.inf
        conds.append(c)
        if best is None or c < best.cond:
            best = ExcitationResult(traj, c, conds, solver.solver_id().name())
    assert best is not None
    if not math.isfinite(best.cond):
        raise RuntimeError("excitation: no start reached a feasible trajectory; raise optimisation.starts")
    best.start_conds = conds
    return best


def _feasible_start(rng, amplitude, n, L, start_basis, grid_basis, lo, hi, vmax) -> np.ndarray:
    """Random coefficients projected onto the zero-start equalities (eq. 4.14) and scaled into the limits, so that
    the solver starts feasible for all (linear) constraints."""
    qa0, qb0, va0, vb0, aa0, ab0 = start_basis
    qa, qb, va, vb = grid_basis
    eq = np.vstack([np.concatenate([qa0[0], qb0[0]]), np.concatenate([va0[0], vb0[0]]),
                    np.concatenate([aa0[0], ab0[0]])])                       # [3, 2L]
    null = np.eye(2 * L) - eq.T @ np.linalg.solve(eq @ eq.T, eq)
    x = rng.uniform(-1, 1, (n, 2 * L)) * amplitude @ null.T
    pos, vel = x @ np.hstack([qa, qb]).T, x @ np.hstack([va, vb]).T        # [n, T]
    with np.errstate(divide="ignore"):
        ratio = np.min(np.stack([np.min(np.where(pos > 0, hi[:, None] / pos, np.inf), axis=1),
                                 np.min(np.where(pos < 0, lo[:, None] / pos, np.inf), axis=1),
                                 vmax / np.max(np.abs(vel), axis=1)]), axis=0)
    x *= np.minimum(1.0, 0.95 * ratio)[:, None]
    return np.concatenate([x[:, :L].ravel(), x[:, L:].ravel()])


def _into_limits(traj: FourierTrajectory, lo: np.ndarray, hi: np.ndarray, vmax: np.ndarray) -> FourierTrajectory:
    """Scale each joint's coefficients down just enough to meet the limits on a fine grid (the constraints hold
    only at the constraint samples; scaling keeps the zero start since ``lo < 0 < hi``)."""
    q, qd, _ = traj.evaluate(np.linspace(0.0, traj.period, 4000))
    with np.errstate(divide="ignore"):
        ratio = np.min(np.stack([np.min(np.where(q > 0, hi / q, np.inf), axis=0),
                                 np.min(np.where(q < 0, lo / q, np.inf), axis=0),
                                 vmax / np.max(np.abs(qd), axis=0)]), axis=0)
    f = np.minimum(1.0, ratio)[:, None]
    return FourierTrajectory(traj.a * f, traj.b * f, traj.omega_f)


def _feasible(traj: FourierTrajectory, lo: np.ndarray, hi: np.ndarray, vmax: np.ndarray, tol: float = 1e-3) -> bool:
    """Limits checked on a 10× finer grid than the constraints; ``tol`` [rad, rad/s] admits the overshoot between
    constraint samples (≈1e-4), far inside the 2° margin."""
    t = np.linspace(0.0, traj.period, 4000)
    q, qd, qdd = traj.evaluate(t)
    start = traj.evaluate(np.zeros(1))
    return bool(np.all(q >= lo - tol) and np.all(q <= hi + tol) and np.all(np.abs(qd) <= vmax + tol)
                and all(np.all(np.abs(s) < 1e-6) for s in start))


def check_collisions(desc: RobotDescription, q: np.ndarray) -> list[tuple[int, str, str]]:
    """Self-collisions along ``q [T, n]`` with the description's collision primitives (Drake SceneGraph).

    Pairs already in contact at the zero configuration are treated as modelling artefacts of the primitive
    shapes and ignored. Returns ``(sample index, geometry A, geometry B)`` for every new contact."""
    checker = CollisionChecker(desc)

    def pairs(qk: np.ndarray) -> set[tuple[str, str]]:
        return {tuple(sorted(p)) for p in checker.colliding_pairs(qk)}

    home = pairs(np.zeros(desc.n))
    hits = []
    for k, qk in enumerate(np.asarray(q, dtype=float)):
        for a_, b_ in sorted(pairs(qk) - home):
            hits.append((k, a_, b_))
    return hits


def protocol_trajectory(traj: FourierTrajectory, speed_factors: list[float], rate_hz: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The §4.1 protocol: the period concatenated once per speed factor, each copy time-scaled by ``1/factor``
    (slower), sampled at ``rate_hz``. Periodicity makes the joins continuous in q, q̇, q̈ (q̇, q̈ scale with the
    factor). Returns ``t, q, qd, qdd``; the experiment repeats it ``protocol.repetitions`` times and averages."""
    ts, qs, qds, qdds = [], [], [], []
    t0 = 0.0
    for f in speed_factors:
        if not f > 0:
            raise ValueError(f"protocol.speed_factors must be positive, got {f}")
        dur = traj.period / f
        t_loc = np.arange(0.0, dur, 1.0 / rate_hz)
        q, qd, qdd = traj.evaluate(t_loc * f)
        ts.append(t0 + t_loc)
        qs.append(q)
        qds.append(qd * f)
        qdds.append(qdd * f * f)
        t0 += dur
    return np.concatenate(ts), np.concatenate(qs), np.concatenate(qds), np.concatenate(qdds)


def load_shipped_excitation(name: str = "iiwa14_excitation") -> tuple[FourierTrajectory, dict[str, Any]]:
    """A precomputed optimal excitation shipped in ``proprio/configs/<name>.yaml`` (coefficients and provenance)."""
    source = f"{name}.yaml"
    data = load_typed(ShippedExcitation, read_yaml(text=resources.files("proprio.configs").joinpath(source).read_text(),
                                                   source=source), source)
    a, b = np.asarray(data.a, dtype=float), np.asarray(data.b, dtype=float)
    if a.ndim != 2 or a.shape != b.shape:
        raise ConfigError(f"{source}: a and b must be matrices of the same shape [joints][harmonics]")
    traj = FourierTrajectory(a=a, b=b, omega_f=data.omega_f)
    return traj, {k: v for k, v in dataclasses.asdict(data).items() if k not in ("a", "b")}


def protocol_piecewise(traj: FourierTrajectory, speed_factors: list[float], rate_hz: float = 100.0):
    """The §4.1 protocol as a Drake ``PiecewisePolynomial`` (cubic Hermite through the exact q, q̇ at ``rate_hz``),
    ready for a ``TrajectorySource`` or the twin."""
    from pydrake.trajectories import PiecewisePolynomial

    t, q, qd, _ = protocol_trajectory(traj, speed_factors, rate_hz)
    return PiecewisePolynomial.CubicHermite(t, q.T, qd.T)
