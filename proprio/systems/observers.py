"""External-wrench observers at the flange, from joint torques (§3.1 eq. 3.8–3.14; De Luca's momentum observer).

Conventions (DESIGN.md): the measured link-side torque is ``τ_J = τ_rbd(q, q̇, q̈) + τ_int − Jᵀ f_ext`` where
``τ_int`` is what a model adds to the rigid body (link friction, a learned residual) and ``f_ext`` is the wrench
the environment exerts ON the robot at the flange, world frame, order ``[fx, fy, fz, mx, my, mz]`` (N, N·m). So
the external joint torque is

    τ_ext = Jᵀ f_ext = τ_dyn − τ_J,        τ_dyn = τ_rbd + τ_int                      (eq. 3.10)
    f_ext = J⁻ᵀ τ_ext                                                                   (eq. 3.11–3.12)

Two ways to get τ_ext:

* :class:`JacobianWrenchObserver` — direct: τ_ext = τ_dyn − τ_J with τ_dyn from a dynamics model fed with filtered
  (q, q̇, q̈). Needs accelerations, no memory, no lag.
* :class:`~proprio.systems.momentum_observer.MomentumObserver` — De Luca's generalised-momentum residual (needs no
  q̈), a first-order low-pass of τ_ext with time constant 1/K_O per joint; in :mod:`proprio.systems.momentum_observer`.

As Systems (one per stage, C++ where the work is linear): :class:`JacobianWrenchObserver` (τ_dyn − τ_J, a
``MatrixGain``), the momentum observer (the rigid-body terms p, τ_g + Cᵀq̇ and J from Drake's plant, then the
recursion as a discrete ``LinearSystem``) and :class:`WrenchMap`, which maps both
τ̂_ext to wrenches with ONE Jacobian and ONE eigen-decomposition per step. Each Python System exposes its step
function (``calc``) so that :mod:`proprio.online` drives the same code without a Simulator.

The Jacobian pseudo-inverse (eq. 3.12, the arm is redundant: 7 equations, 6 or 3 unknowns) is a weighted,
adaptively damped least-squares solve of ``Jᵀ w = τ_ext``:

    w = argmin ‖W^½ (Jᵀ w − τ_ext)‖² + λ² ‖w‖²,   λ² = λ_max² (1 − (σ_min/ε)²) if σ_min < ε else 0,

with σ_min the smallest singular value of ``W^½ Jᵀ``. Away from singularities (σ_min ≥ ε) it is the exact weighted
least-squares solution; near them the damping bounds the output and the ``unreliable`` flag is raised: a torque error
δτ maps to a wrench error of up to ‖δτ‖/σ_min (ε = 0.02 → 0.1 N·m of torque error can give 5 N). Our Jacobian rows are
[ω; v] (Drake's order), so the unknown of ``[J_v; J_ω]ᵀ w = τ`` is ``w = [f; m]``. Force-only mode (3-D) solves with
J_v alone and reports zero moment: a payload exerts no moment about its own CoM, so put the contact point there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, MatrixGain, Multiplexer
from scipy.linalg.lapack import dposv, dpotrf, dsyevd

from proprio.description import RobotDescription
from proprio.kinematics import ChainGeometry, chain_geometry, point_jacobian
from proprio.systems.momentum_observer import DrakeArm

__all__ = ["WrenchMapping", "wrench_from_joint_torque", "WrenchSolver", "jacobian_wrench", "WrenchMapStep", "WrenchMap",
           "JacobianWrenchObserver"]

_VW = [3, 4, 5, 0, 1, 2]   # rows of our [ω; v] Jacobian in [v; ω] order, so that Jᵀ[f; m] = τ


@dataclass(frozen=True)
class WrenchMapping:
    """How joint torques are mapped to a Cartesian wrench (eq. 3.12).

    Attributes:
        force_only: solve for the 3-D force only (moment reported as 0); right when the contact point is the CoM of
            a payload or a point contact.
        sigma_threshold: ε — below this smallest singular value of ``W^½ Jᵀ`` the estimate is flagged unreliable
            and damping starts [m in force-only mode; mixed m / 1 for 6-D since J_v is in m and J_ω unitless].
        damping_max: λ_max, the damping reached at an exact singularity (same units as the singular values).
        joint_weights: per-joint weights W (e.g. 1/σ² of each torque sensor's noise); None = all ones.
        contact_point: the point where the wrench acts, in the flange frame [m] (default: the flange origin).
    """
    force_only: bool = False
    sigma_threshold: float = 0.02
    damping_max: float = 0.02
    joint_weights: tuple[float, ...] | None = None
    contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not self.sigma_threshold > 0:
            raise ValueError(f"WrenchMapping.sigma_threshold must be > 0, got {self.sigma_threshold}")
        if not self.damping_max >= 0:
            raise ValueError(f"WrenchMapping.damping_max must be >= 0, got {self.damping_max}")
        if self.joint_weights is not None and not np.all(np.asarray(self.joint_weights) > 0):
            raise ValueError(f"WrenchMapping.joint_weights must all be > 0, got {self.joint_weights}")


def _damping(s_min: np.ndarray | float, mapping: WrenchMapping) -> np.ndarray | float:
    """λ² = λ_max² (1 − (σ_min/ε)²) below ε, else 0 (the adaptive damping of the module docstring)."""
    eps = mapping.sigma_threshold
    return np.where(s_min < eps, mapping.damping_max ** 2 * (1.0 - (s_min / eps) ** 2), 0.0)


def _sqrt_weights(mapping: WrenchMapping, n: int) -> np.ndarray | None:
    if mapping.joint_weights is None:
        return None
    sqrt_w = np.sqrt(np.asarray(mapping.joint_weights, float))
    if sqrt_w.shape != (n,):
        raise ValueError(f"WrenchMapping.joint_weights has {sqrt_w.size} entries, the arm has {n} joints")
    return sqrt_w


def wrench_from_joint_torque(jac: np.ndarray, tau_ext: np.ndarray, mapping: WrenchMapping = WrenchMapping()
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve ``Jᵀ w = τ_ext`` for the wrench, batched (eq. 3.12 with a weighted, damped pseudo-inverse).

    Args:
        jac: geometric Jacobians ``[N,6,n]`` of the contact point, rows [ω; v], world frame.
        tau_ext: external joint torques ``[N,n]`` [N·m] (= τ_dyn − τ_J).
        mapping: solver options.

    Returns:
        ``wrench [N,6]`` = [f; m] (N, N·m; moment 0 in force-only mode), ``manipulability [N]`` = ∏σ_i =
        √det(J W Jᵀ) of the solved system (Yoshikawa), ``unreliable [N]`` bool (σ_min < ε).
    """
    jac = np.asarray(jac, dtype=float)
    tau_ext = np.asarray(tau_ext, dtype=float)
    a_t = np.swapaxes(jac[:, _VW[:3]] if mapping.force_only else jac[:, _VW], 1, 2)        # Jᵀ [N,n,k]
    sqrt_w = _sqrt_weights(mapping, a_t.shape[1])
    if sqrt_w is not None:                                                                 # W^½ Jᵀ, W^½ τ
        a_t, tau_ext = sqrt_w[:, None] * a_t, sqrt_w * tau_ext
    u, s, vt = np.linalg.svd(a_t, full_matrices=False)                                     # [N,n,k],[N,k],[N,k,k]
    s_min = s[:, -1]
    gain = s / (s ** 2 + _damping(s_min, mapping)[:, None])                                # damped 1/σ
    b = (np.swapaxes(u, 1, 2) @ tau_ext[:, :, None])[:, :, 0]                              # Uᵀ W^½ τ
    sol = (np.swapaxes(vt, 1, 2) @ (gain * b)[:, :, None])[:, :, 0]                        # V diag(gain) Uᵀ W^½ τ
    wrench = np.zeros((jac.shape[0], 6))
    wrench[:, :sol.shape[1]] = sol
    return wrench, np.prod(s, axis=1), s_min < mapping.sigma_threshold


class WrenchSolver:
    """:func:`wrench_from_joint_torque` for ONE configuration, for the Systems' per-step work, where numpy's per-call
    overhead dominates the batched path (≈33 µs at N = 1). The same damped least-squares solution
    ``w = (J W Jᵀ + λ²I)⁻¹ J W τ`` from the k×k matrix ``J W Jᵀ = V diag(σ²) Vᵀ``, in two ways:

    * away from singularities (the common case, found by the Cholesky factorisation of ``J W Jᵀ − ε²I`` succeeding,
      i.e. σ_min > ε): λ = 0, and ONE LAPACK ``dposv`` gives w for all torque vectors and the Cholesky factor, whose
      diagonal's product is ∏σ = √det(J W Jᵀ);
    * otherwise the eigen-decomposition (``dsyevd``): σ_min, the damping λ², ``w = V diag(1/(σ² + λ²)) Vᵀ J W τ``.

    Our [ω; v] rows would give the unknown in [m; f] order; the rows are permuted instead (below). Forming J W Jᵀ
    squares the condition number, harmless here (σ_max/ε ≈ 10² → 10⁴). :meth:`solve` maps several torque vectors
    through the same factorisation (both observers share J(q)); ``solver(jac [6,n], tau_ext [n])`` returns
    ``[f; m (6), manipulability, unreliable]``. The rows of J are taken in [v; ω] order, so the unknown is [f; m] as
    returned."""

    def __init__(self, mapping: WrenchMapping, n: int):
        self.mapping = mapping
        self._rows = np.array(_VW[:3] if mapping.force_only else _VW)          # J rows [v] or [v; ω]: w = [f; m]
        self._sqrt_w = _sqrt_weights(mapping, n)
        self._force_only = mapping.force_only
        self._shift = mapping.sigma_threshold ** 2 * np.eye(len(self._rows))   # ε² I

    def solve(self, jac: np.ndarray, tau_ext: np.ndarray) -> tuple[np.ndarray, float, float]:
        """``jac [6,n]`` (rows [ω; v], world frame, of the contact point) and ``tau_ext [m,n]`` [N·m] →
        ``(wrench [m,6] [f; m] N, N·m, manipulability ∏σ, unreliable 1.0/0.0)``."""
        wrench = np.empty((tau_ext.shape[0], 6))
        return (wrench, *self.solve_into(jac, tau_ext, wrench))

    def solve_into(self, jac: np.ndarray, tau_ext: np.ndarray, wrench_out: np.ndarray) -> tuple[float, float]:
        """:meth:`solve` with the wrenches written into ``wrench_out [m,6]`` →
        ``(manipulability ∏σ, unreliable 1.0/0.0)``."""
        a = jac.take(self._rows, axis=0)                             # J [k,n], rows [v; ω] or [v]
        if self._sqrt_w is not None:
            a, tau_ext = a * self._sqrt_w, tau_ext * self._sqrt_w
        aat = a @ a.T
        force = wrench_out[:, :3] if self._force_only else wrench_out
        if self._force_only:
            wrench_out[:, 3:] = 0.0
        if dpotrf(aat - self._shift)[1] == 0:                        # σ_min > ε: no damping (positional
            chol, sol, info = dposv(aat, np.dot(a, tau_ext.T))       # arguments: f2py parses keywords slowly)
            if info != 0:
                raise np.linalg.LinAlgError(f"WrenchSolver: LAPACK dposv failed (info = {info})")
            force[:] = sol.T                                         # rows (J Jᵀ)⁻¹ J τ = [f; m] or f
            return math.prod(chol.diagonal().tolist()), 0.0          # ∏σ = ∏ diag(U), J Jᵀ = UᵀU
        lam, v, info = dsyevd(aat)                                   # J Jᵀ = V diag(σ²) Vᵀ, ascending
        if info != 0:
            raise np.linalg.LinAlgError(f"WrenchSolver: LAPACK dsyevd did not converge (info = {info})")
        sq = lam.tolist()                                            # σ², ascending (≥ 0 up to rounding)
        s_min = math.sqrt(max(sq[0], 0.0))
        unreliable = s_min < self.mapping.sigma_threshold
        if unreliable:                                               # (not when σ_min = ε to rounding)
            lam = lam + float(_damping(s_min, self.mapping))
        force[:] = ((tau_ext @ a.T) @ v / lam) @ v.T                 # rows (J Jᵀ + λ²)⁻¹ J τ = [f; m] or f
        return (math.sqrt(math.prod(sq)) if sq[0] > 0 else 0.0), float(unreliable)    # ∏σ (0 if σ_min = 0)

    def __call__(self, jac: np.ndarray, tau_ext: np.ndarray) -> np.ndarray:
        wrench, manip, flag = self.solve(jac, np.asarray(tau_ext, dtype=float)[None, :])
        return np.concatenate((wrench[0], (manip, flag)))


def jacobian_wrench(desc: RobotDescription | ChainGeometry, q: np.ndarray, tau_meas: np.ndarray,
                    tau_dyn: np.ndarray, mapping: WrenchMapping = WrenchMapping()
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Jacobian wrench observer, vectorised over samples: ``f̂ = J⁻ᵀ(q) (τ_dyn − τ_meas)`` (eq. 3.12).

    Args:
        desc: robot description (or its precomputed :class:`ChainGeometry`) for the flange Jacobian.
        q: joint positions ``[N,n]`` [rad]; tau_meas: measured τ_J ``[N,n]`` [N·m]; tau_dyn: model torque ``[N,n]``.
        mapping: pseudo-inverse options (:class:`WrenchMapping`).

    Returns:
        ``(wrench [N,6] [fx, fy, fz, mx, my, mz] on the robot at the contact point, world frame,
        manipulability [N], unreliable [N] bool)``.
    """
    geo = desc if isinstance(desc, ChainGeometry) else chain_geometry(desc)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    tau_ext = np.atleast_2d(np.asarray(tau_dyn, dtype=float)) - np.atleast_2d(np.asarray(tau_meas, dtype=float))
    if tau_ext.shape != q.shape:
        raise ValueError(f"jacobian_wrench: q, tau_meas and tau_dyn must have the same shape [N,n], got q {q.shape}, "
                         f"tau_dyn − tau_meas {tau_ext.shape}")
    jac = point_jacobian(geo, q, np.asarray(mapping.contact_point, dtype=float))
    return wrench_from_joint_torque(jac, tau_ext, mapping)


class WrenchMapStep(LeafSystem):
    """:class:`WrenchMap`'s Python System: input ``inputs`` = ``[q or vec(J); τ̂_ext,1; …; τ̂_ext,m]`` (one stacked port: each
    input evaluation from Python costs about a microsecond), output ``estimate`` (:meth:`WrenchMap.calc`)."""

    def __init__(self, owner: "WrenchMap"):
        LeafSystem.__init__(self)
        n, m = owner.n, len(owner.sources)
        self._owner, self._n, self._m = owner, n, m
        self._k = 6 * n if owner.jacobian_input else n
        self._inputs = self.DeclareVectorInputPort("inputs", self._k + m * n)
        self.DeclareVectorOutputPort("estimate", 6 * m + 2 + m * n, self._calc)
        self._out = owner.estimate_buffer()

    def _calc(self, context, output) -> None:
        x, k = self._inputs.Eval(context), self._k
        tau_ext = x[k:].reshape(self._m, self._n)
        if self._owner.jacobian_input:
            self._owner.calc_jacobian(x[:k].reshape(6, self._n), tau_ext, self._out)
        else:
            self._owner.calc(x[:k], tau_ext, self._out)
        output.SetFromVector(self._out[0])


class WrenchMap(Diagram):
    """The Cartesian mapping of eq. 3.12 shared by the observers: ``f̂ = J⁻ᵀ(q) τ̂_ext`` for each observer's τ̂_ext,
    with ONE Jacobian (Drake's ``CalcJacobianSpatialVelocity`` on a cached plant context) and ONE eigen-decomposition
    (:class:`WrenchSolver`) per step for all of them.

    Input ports: ``q`` (n) [rad] — or, with ``jacobian_input``, ``jacobian`` (6n) the contact point's Jacobian (rows
    [ω; v], world frame, row-major, e.g. :class:`MomentumObserver`'s) —; ``tau_ext_<source>`` (n) [N·m] for each name
    in ``sources`` (default ``("jacobian", "momentum")``). Output ports: ``estimate`` (6m + 2 + mn), all of it stacked
    ``[wrench_<s>…, manipulability, unreliable, tau_ext_<s>…]`` — the one port a logger needs — and, split from it in
    C++, ``wrench_<source>`` (6) [fx, fy, fz, mx, my, mz] on the robot at the contact point, world frame (N, N·m;
    moment 0 in force-only mode); ``manipulability`` (1) = √det(J W Jᵀ); ``unreliable`` (1) 1.0 when σ_min <
    ``mapping.sigma_threshold`` else 0.0. Inside: ``Multiplexer`` → :class:`WrenchMapStep` → ``Demultiplexer``.
    """

    def __init__(self, desc: RobotDescription, mapping: WrenchMapping = WrenchMapping(),
                 sources: tuple[str, ...] = ("jacobian", "momentum"), jacobian_input: bool = False):
        Diagram.__init__(self)
        n, m = desc.n, len(sources)
        self.n, self.sources, self.jacobian_input = n, tuple(sources), jacobian_input
        self._arm = None if jacobian_input else DrakeArm(desc)     # (with a Jacobian input, no plant of its own)
        self._solver = WrenchSolver(mapping, n)
        self._contact = np.asarray(mapping.contact_point, dtype=float)
        k = 6 * n if jacobian_input else n
        builder = DiagramBuilder()
        stack = builder.AddNamedSystem("stack", Multiplexer([k] + [n] * m))
        step = builder.AddNamedSystem("solve", WrenchMapStep(self))
        split = builder.AddNamedSystem("split", Demultiplexer([6] * m + [1, 1, m * n]))
        builder.ExportInput(stack.get_input_port(0), "jacobian" if jacobian_input else "q")
        for i, s in enumerate(self.sources):
            builder.ExportInput(stack.get_input_port(1 + i), f"tau_ext_{s}")
        builder.Connect(stack.get_output_port(), step.get_input_port())
        builder.Connect(step.get_output_port(), split.get_input_port())
        builder.ExportOutput(step.get_output_port(), "estimate")
        for i, s in enumerate(self.sources):
            builder.ExportOutput(split.get_output_port(i), f"wrench_{s}")
        builder.ExportOutput(split.get_output_port(m), "manipulability")
        builder.ExportOutput(split.get_output_port(m + 1), "unreliable")
        builder.BuildInto(self)
        self.set_name("wrench")

    def estimate_buffer(self) -> tuple[np.ndarray, ...]:
        """A preallocated ``estimate`` vector with its views ``(vector, wrenches [m,6], [manipulability,
        unreliable], τ̂_ext [m,n])``, for the ``out`` argument of :meth:`calc` / :meth:`calc_jacobian`."""
        n, m = self.n, len(self.sources)
        v = np.empty(6 * m + 2 + m * n)
        return v, v[:6 * m].reshape(m, 6), v[6 * m:6 * m + 2], v[6 * m + 2:].reshape(m, n)

    def calc(self, q: np.ndarray, tau_ext: np.ndarray, out: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
        """The ``estimate`` vector for ``q [n]`` and ``tau_ext [m,n]`` (one row per source) — the step function
        (written into ``out``, an :meth:`estimate_buffer`, when given)."""
        if self._arm is None:
            raise ValueError("WrenchMap: built with jacobian_input=True; call calc_jacobian(J, tau_ext)")
        return self.calc_jacobian(self._arm.flange_jacobian(q, self._contact), tau_ext, out)

    def calc_jacobian(self, jac: np.ndarray, tau_ext: np.ndarray, out: tuple[np.ndarray, ...] | None = None
                      ) -> np.ndarray:
        """The same from the contact point's Jacobian ``jac [6,n]`` (rows [ω; v], world) — the step function with
        ``jacobian_input`` (written into ``out``, an :meth:`estimate_buffer`, when given; a new vector otherwise)."""
        vector, wrench, flags, tau = self.estimate_buffer() if out is None else out
        flags[0], flags[1] = self._solver.solve_into(jac, tau_ext, wrench)
        tau[:] = tau_ext
        return vector


class JacobianWrenchObserver(Diagram):
    """The direct observer's joint-space part, τ̂_ext = τ_dyn − τ_meas (eq. 3.10), in C++ (``Multiplexer`` →
    ``MatrixGain [I −I]``): direct feedthrough, no state, no lag. Its wrench is :class:`WrenchMap`'s
    ``wrench_jacobian`` (the same solver as :func:`jacobian_wrench`).

    Input ports (size n): ``tau_dyn`` [N·m] (model torque), ``tau_meas`` [N·m] (measured τ_J).
    Output port: ``tau_ext`` (n) [N·m].
    """

    def __init__(self, n: int):
        Diagram.__init__(self)
        builder = DiagramBuilder()
        mux = builder.AddNamedSystem("stack", Multiplexer([n, n]))
        diff = builder.AddNamedSystem("difference", MatrixGain(np.hstack([np.eye(n), -np.eye(n)])))
        builder.Connect(mux.get_output_port(), diff.get_input_port())
        builder.ExportInput(mux.get_input_port(0), "tau_dyn")
        builder.ExportInput(mux.get_input_port(1), "tau_meas")
        builder.ExportOutput(diff.get_output_port(), "tau_ext")
        builder.BuildInto(self)
        self.set_name("jacobian_observer")
