"""Newton–Euler inertial-parameter regressor ``τ = Y(q, q̇, q̈) φ`` (thesis eq. 3.35–3.49), batched over samples.

Standard parameter vector ``φ ∈ ℝ^{12n}``: per joint/link ``j`` a block of 12 numbers, in this order::

    [m, m·cx, m·cy, m·cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz, Fv, Fc]

* ``m`` [kg]; ``m·c`` [kg·m] the first mass moment, ``c`` the CoM in the *link frame* of ``desc`` (URDF semantics:
  the joint frame rotated by ``q_j``);
* ``I`` [kg·m²] the rotational inertia **about the link-frame origin** (not the CoM), link-frame axes, tensor entries
  (``Ixy`` is the matrix element, i.e. ``−∫xy dm``);
* ``Fv`` [N·m·s/rad] viscous and ``Fc`` [N·m] Coulomb friction of joint ``j``: ``τ_f = Fv q̇ + Fc sgn(q̇)``, the
  one law of :mod:`proprio.friction_law`: ``sgn`` is the smooth ``tanh(q̇ / scale)`` with ``scale =
  coulomb_velocity_scale`` [rad/s] (``None``, the default: the library's smoothing; ``0``: the exact ``sign``).

Drive-torque arms (``desc.drive`` with ``tau_kind: drive``, :mod:`proprio.drive_description`) append ``3n`` drive
parameters after the ``12n``: per motor ``k`` the reflected rotor inertia ``Ia<k>`` [kg·m²], motor viscous ``Fvm<k>``
[N·m·s/rad] and Coulomb ``Fcm<k>`` [N·m] friction, with the columns of ``τ = Cᵀ(I_a ⊙ C q̈ + F_v,m ⊙ C q̇ +
F_c,m ⊙ sgn(C q̇))`` (:func:`drive_columns`; ``C`` the normalised coupling). Constant drive offsets are the
estimators' ``offsets`` unknowns.

The recursion is the thesis' Algorithm 4.7 in link frames: motion (ω, ω̇, linear acceleration of the origin with
``−g`` folded in) is propagated outwards, and instead of propagating wrenches inwards, every joint ``i ≤ j`` is
projected onto link ``j``'s wrench through joint ``i``'s unit screw expressed in frame ``j`` (axis ``u_ij``, moment
``v_ij = u_ij × (o_j − o_i)``): ``τ_i ← u_ij · n_j + v_ij · f_j`` (eq. 3.43–3.45 collapsed to one projection).

Memory layout and cost: every internal array is component-major with the sample axis last (``[3, S]``), samples
processed in chunks of :data:`CHUNK`, so every operation is a long vectorised loop. The constant joint geometry is
kept as sparse rows (:class:`RegressorGeometry`): with axis-aligned joint frames (the iiwa, the LWR) a frame change is
a handful of multiply-adds on ``[3, S]`` arrays, not a 3×3 product; the projection of link ``j``'s 6 × 10 wrench
regressor on the screws of joints ``i ≤ j`` is one fused ``einsum`` writing straight into the output, and the blocks
below the diagonal (joint ``i`` never sees links ``j < i``) are never computed nor touched. :func:`regressor`
returns ``Y [N, n, 12n]`` as a strided *view* of a ``[n, 12n, N]`` buffer (``Y.base``): estimators that form normal
equations use the buffer directly (:func:`regressor_buffer`), each joint row block ``[12n, N]`` being contiguous.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from proprio import friction_law
from proprio.description import Link, RobotDescription, rpy_to_matrix
from proprio.drive_description import DriveDescription

__all__ = ["PARAMS_PER_JOINT", "PARAMETER_KEYS", "DRIVE_KEYS", "parameter_names", "standard_parameters",
           "parameters_to_links", "friction_from_parameters", "drive_from_parameters", "regressor", "regressor_buffer",
           "predict", "RegressorGeometry", "regressor_geometry", "drive_columns",
           "drive_identified", "n_parameters", "drive_torque"]

PARAMETER_KEYS = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz", "Fv", "Fc")
PARAMS_PER_JOINT = len(PARAMETER_KEYS)
DRIVE_KEYS = ("Ia", "Fvm", "Fcm")   # per motor: reflected rotor inertia, motor viscous and Coulomb friction


def drive_identified(desc: RobotDescription) -> bool:
    """True when ``desc``'s τ is a drive torque, so that its drive terms are columns of the regressor."""
    return desc.drive is not None and desc.drive.in_tau


def n_parameters(desc: RobotDescription) -> int:
    """Length of the standard parameter vector of ``desc``: ``12n`` (+ ``3n`` drive parameters)."""
    return (PARAMS_PER_JOINT + (len(DRIVE_KEYS) if drive_identified(desc) else 0)) * desc.n


def parameter_names(n: int, drive: bool = False) -> list[str]:
    """Names of the standard parameters, e.g. ``"Izz3"`` (1-based joint/link index, as in the thesis), then with
    ``drive`` the drive parameters ``Ia1..Ian, Fvm1.., Fcm1..`` (1-based motor index)."""
    names = [f"{k}{j + 1}" for j in range(n) for k in PARAMETER_KEYS]
    return names + ([f"{k}{j + 1}" for k in DRIVE_KEYS for j in range(n)] if drive else [])


def drive_columns(drive: DriveDescription, qd: np.ndarray, qdd: np.ndarray, coulomb_velocity_scale: float | None,
                  out: np.ndarray | None = None) -> np.ndarray:
    """Regressor columns of the drive terms ``D [n, 3n, N]``: ``τ_i = Σ_c D[i, c] p_c`` with
    ``p = [I_a, F_v,m, F_c,m]`` (:meth:`~proprio.drive_description.DriveDescription.parameters`), i.e.
    ``τ_drive = Cᵀ(I_a ⊙ C q̈ + F_v,m ⊙ C q̇ + F_c,m ⊙ sgn(C q̇))`` [N·m] for ``qd, qdd [n, N]`` (joint-major) in
    rad/s, rad/s²; ``C`` the normalised coupling (motor ``k`` moves with joint ``i`` when ``C[k, i] ≠ 0``)."""
    c = drive.normalized_coupling
    n = c.shape[0]
    v, a = c @ qd, c @ qdd                                      # motor velocity, acceleration in joint units
    out = np.zeros((n, 3 * n, qd.shape[1])) if out is None else out
    for g, f in enumerate((a, v, friction_law.smooth_sign(v, coulomb_velocity_scale))):
        for k in range(n):
            for i in np.flatnonzero(c[k]):
                np.multiply(f[k], c[k, i], out=out[i, g * n + k])
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def drive_torque(desc: RobotDescription, qd: np.ndarray, qdd: np.ndarray, coulomb_velocity_scale: float | None
                 ) -> np.ndarray:
    """The drive terms in a drive-torque arm's τ ``[N, n]`` [N·m] (rotor inertia, motor friction on the coupled
    motor velocity; not the constant offsets) for ``qd, qdd [N, n]`` (or ``[n]``): :func:`drive_columns` times the
    description's drive parameters. Zeros when ``desc``'s τ is not a drive torque."""
    single = np.ndim(qd) == 1
    qd, qdd = np.atleast_2d(np.asarray(qd, dtype=float)), np.atleast_2d(np.asarray(qdd, dtype=float))
    if not drive_identified(desc):
        tau = np.zeros_like(qd)
    else:
        cols = drive_columns(desc.drive, qd.T, qdd.T, coulomb_velocity_scale)
        tau = np.einsum("ics,c->si", cols, desc.drive.parameters())
    return tau[0] if single else tau


def standard_parameters(desc: RobotDescription) -> np.ndarray:
    """The standard parameter vector ``φ [12n (+3n)]`` of ``desc`` (order in the module docstring). Missing friction
    counts as zero."""
    out = np.zeros(n_parameters(desc))
    if drive_identified(desc):
        out[PARAMS_PER_JOINT * desc.n:] = desc.drive.parameters()
    for j, link in enumerate(desc.links):
        m, c = link.mass, np.asarray(link.com_xyz, dtype=float)
        i_o = link.inertia_matrix_link() + m * (c @ c * np.eye(3) - np.outer(c, c))   # parallel axes: CoM → origin
        out[12 * j:12 * j + 10] = [m, *(m * c), i_o[0, 0], i_o[0, 1], i_o[0, 2], i_o[1, 1], i_o[1, 2], i_o[2, 2]]
        if desc.has_friction:
            out[12 * j + 10] = desc.friction_viscous[j]
            out[12 * j + 11] = desc.friction_coulomb[j]
    return out


def parameters_to_links(phi: np.ndarray, template: RobotDescription) -> list[Link]:
    """Links (mass, CoM, inertia about the CoM with ``com_rpy = 0``) from a standard parameter vector; names and
    collision geometry are taken from ``template``. A link with ``m ≤ 0`` cannot have a CoM: :class:`ValueError`."""
    phi = np.asarray(phi, dtype=float)
    if phi.shape != (n_parameters(template),):
        raise ValueError(f"parameters_to_links: phi must have {n_parameters(template)} entries, got {phi.shape}")
    links = []
    for j, old in enumerate(template.links):
        b = phi[12 * j:12 * j + 10]
        m = float(b[0])
        if not m > 0.0:
            raise ValueError(f"parameters_to_links: m{j + 1} = {m:.4g} kg is not positive; the parameter set is not "
                             "a physical body (use the SDP estimate for a rebuildable model)")
        c = b[1:4] / m
        i_o = np.array([[b[4], b[5], b[6]], [b[5], b[7], b[8]], [b[6], b[8], b[9]]])
        i_c = i_o - m * (c @ c * np.eye(3) - np.outer(c, c))
        links.append(Link(name=old.name, mass=m, com_xyz=tuple(float(x) for x in c),
                          inertia_com=tuple(float(i_c[a, b]) for a, b in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2),
                                                                          (1, 2))),
                          com_rpy=(0.0, 0.0, 0.0), collision=old.collision))
    return links


def friction_from_parameters(phi: np.ndarray, n: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(viscous, coulomb)`` per joint from a standard parameter vector."""
    p = np.asarray(phi, dtype=float)[:PARAMS_PER_JOINT * n].reshape(n, PARAMS_PER_JOINT)
    return tuple(float(x) for x in p[:, 10]), tuple(float(x) for x in p[:, 11])


def drive_from_parameters(phi: np.ndarray, desc: RobotDescription, offsets: np.ndarray | None = None
                          ) -> DriveDescription | None:
    """``desc``'s drive block with the drive parameters of ``φ`` (and the offsets ``[n]`` [N·m] when given);
    ``desc.drive`` unchanged when its τ is not a drive torque."""
    if not drive_identified(desc):
        return desc.drive
    p = np.asarray(phi, dtype=float)[PARAMS_PER_JOINT * desc.n:]
    return desc.drive.with_parameters(p, desc.drive.offset if offsets is None else offsets)


_Terms = tuple[tuple[float, int], ...]     # sparse row of a constant 3×3 matrix: ((coefficient, column), ...)


def _sparse_rows(m: np.ndarray) -> tuple[_Terms, ...]:
    """Rows of a constant matrix as ``(coefficient, column)`` terms, entries within ``1e-14`` of 0 or ±1 snapped to
    them (URDF ``rpy`` of ±π/2 gives entries like 6e-17: rounding noise) so that products skip zero and unit
    factors."""
    rows = []
    for row in m:
        terms = []
        for k, x in enumerate(row):
            x = float(x)
            if abs(x) < 1e-14:
                continue
            if abs(abs(x) - 1.0) < 1e-14:
                x = math.copysign(1.0, x)
            terms.append((x, k))
        rows.append(tuple(sorted(terms, key=lambda t: t[0] < 0)))      # a positive term first: no negation
    return tuple(rows)


@dataclass(frozen=True)
class RegressorGeometry:
    """Constant kinematics of the chain in the form the regressor uses: per joint, the sparse rows (see
    :func:`_sparse_rows`) of its constant matrices, so that every product with them skips zero and unit entries."""
    to_child: tuple[tuple[tuple[_Terms, ...], ...], ...]  # (A1, A2, A3): child ← parent is c·A1 − s·A2 + A3,
    #                                                      A1 = (I−kkᵀ)R_oᵀ, A2 = [k×]R_oᵀ, A3 = kkᵀR_oᵀ (Rodrigues)
    cross_offset: tuple[tuple[_Terms, ...], ...]          # −[o×]: x × o, o the joint origin in the parent frame [m]
    cross_axis: tuple[tuple[_Terms, ...], ...]            # −[k×]: x × k, k the unit joint axis (child frame)
    axis: tuple[_Terms, ...]                              # k as one row ((k_r, r), ...)
    gravity: np.ndarray                                   # [3] gravity in the base frame [m/s²]


def regressor_geometry(desc: RobotDescription) -> RegressorGeometry:
    """Precompute the constant matrices of ``desc`` (joint frames, origins and axes) in sparse form."""
    to_child, cross_o, cross_k, axes = [], [], [], []
    for jt in desc.joints:
        k = np.asarray(jt.axis, dtype=float)
        k = k / np.linalg.norm(k)
        r_o_t = rpy_to_matrix(jt.origin_rpy).T
        kk = np.outer(k, k)
        to_child.append(tuple(_sparse_rows(a) for a in ((np.eye(3) - kk) @ r_o_t, _skew(k) @ r_o_t, kk @ r_o_t)))
        cross_o.append(_sparse_rows(-_skew(np.asarray(jt.origin_xyz, dtype=float))))
        cross_k.append(_sparse_rows(-_skew(k)))
        axes.append(_sparse_rows(k[None])[0])
    g_base = rpy_to_matrix(desc.world_to_base_rpy).T @ np.asarray(desc.gravity, dtype=float)
    return RegressorGeometry(tuple(to_child), tuple(cross_o), tuple(cross_k), tuple(axes), g_base)


def _accumulate(out: np.ndarray, tmp: np.ndarray, terms, add: bool = False) -> None:
    """``out (+)= Σ coef · a · b`` over ``terms`` ``(coef, a, b)`` (``b`` may be ``None``), in place: one multiply per
    product, unit coefficients folded into add/subtract (``tmp``: scratch of ``out``'s shape)."""
    first = not add
    for coef, a, b in terms:
        dst = out if first else tmp
        if b is not None:
            np.multiply(a, b, out=dst)
            a = dst
        if coef != 1.0 and coef != -1.0:
            np.multiply(a, coef, out=dst)
            a, coef = dst, 1.0
        if first:
            if coef == -1.0:
                np.negative(a, out=out)
            elif a is not out:
                np.copyto(out, a)
            first = False
        elif coef == 1.0:
            np.add(out, a, out=out)
        else:
            np.subtract(out, a, out=out)
    if first:
        out[...] = 0.0


def _apply(rows: tuple[_Terms, ...], x: np.ndarray, out: np.ndarray, tmp: np.ndarray, add: bool = False) -> None:
    """``out[r] (+)= Σ_k M[r, k] x[k]`` for a constant ``M`` given by its sparse rows; ``x, out [3, ...]``."""
    for r, row in enumerate(rows):
        _accumulate(out[r], tmp, [(coef, x[k], None) for coef, k in row], add)


def _to_child(plan: tuple[tuple[_Terms, ...], ...], x: np.ndarray, c: np.ndarray, s: np.ndarray,
              out: np.ndarray, tmp: np.ndarray, scratch: np.ndarray) -> None:
    """``out = R_axis(q)ᵀ R_oᵀ x = c·A1 x − s·A2 x + A3 x`` for parent-frame vectors ``x [3, ..., S]``;
    ``c, s [S]`` broadcast; ``scratch [3, ...]`` holds the rows of ``A x`` that are not a single ±x_k."""
    for r in range(3):
        terms = []
        for g, (rows, sign, scale) in enumerate(zip(plan, (1.0, -1.0, 1.0), (c, s, None))):
            row = rows[r]
            if len(row) == 1:
                terms.append((sign * row[0][0], x[row[0][1]], scale))
            elif row:
                _accumulate(scratch[g], tmp, [(coef, x[k], None) for coef, k in row])
                terms.append((sign, scratch[g], scale))
        _accumulate(out[r], tmp, terms)


def _as_samples(name: str, x: np.ndarray, n: int) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[None]
    if x.ndim != 2 or x.shape[1] != n:
        raise ValueError(f"regressor: {name} must be [N,{n}], got shape {x.shape}")
    return x


CHUNK = 8192  # samples per pass: long enough to amortise the per-call overhead, short enough to stay in cache


def regressor_buffer(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     coulomb_velocity_scale: float | None = None,
                     geometry: RegressorGeometry | None = None) -> np.ndarray:
    """The regressor in its native layout ``B [n, 12n, N]``: ``τ_i(s) = Σ_c B[i, c, s] φ_c``.

    Row ``i`` is nonzero only in columns ``12i:`` (joint ``i`` carries links ``i..n−1``, and the drive columns
    ``12n:`` of a drive-torque arm follow), so ``B[i, 12i:]`` is the contiguous block estimators multiply with.
    Inputs ``q, qd, qdd [N, n]`` in rad, rad/s, rad/s².
    """
    geo = geometry or regressor_geometry(desc)
    n = desc.n
    q, qd, qdd = (np.ascontiguousarray(_as_samples(k, v, n).T) for k, v in (("q", q), ("qd", qd), ("qdd", qdd)))
    if not q.shape == qd.shape == qdd.shape:
        raise ValueError(f"regressor: q, qd, qdd must have the same shape, got {q.shape}, {qd.shape}, {qdd.shape}")
    n_s = q.shape[1]
    # zero-filled by the OS on first touch: the blocks below the diagonal are never written (and cost nothing)
    out = np.zeros((n, n_parameters(desc), n_s))
    work = None
    for s0 in range(0, n_s, CHUNK):
        sl = slice(s0, min(s0 + CHUNK, n_s))
        if work is None or work.n_s != sl.stop - s0:
            work = _Workspace(n, sl.stop - s0)
        _rigid_body_block(geo, q[:, sl], qd[:, sl], qdd[:, sl], out[:, :, sl], work)
    for j in range(n):
        out[j, 12 * j + 10] = qd[j]
        out[j, 12 * j + 11] = friction_law.smooth_sign(qd[j], coulomb_velocity_scale)
    if drive_identified(desc):
        drive_columns(desc.drive, qd, qdd, coulomb_velocity_scale, out[:, PARAMS_PER_JOINT * n:])
    return out


class _Workspace:
    """Scratch arrays of :func:`_rigid_body_block` for chunks of ``n_s`` samples (sample axis last)."""

    def __init__(self, n: int, n_s: int):
        self.n_s = n_s
        self.motion = np.empty((2, 3, 3, n_s))       # ping-pong [frame, component, (ω, ω̇, a), S]
        self.screw = np.empty((2, 2, 3, n, n_s))     # ping-pong [frame, (u, v), component, joint i, S]
        self.wrench = np.zeros((6, 10, n_s))         # link regressor A (rows n; f); its structural zeros stay 0
        self.outer = np.empty((3, 3, n_s))           # ω ωᵀ
        self.vec = np.empty((3, n_s))
        self.tmp = np.empty((max(2 * n, 9), n_s))
        self.scratch = np.empty((3, max(2 * n, 3), n_s))


def _link_regressor(w: np.ndarray, wd: np.ndarray, a: np.ndarray, out: np.ndarray, ww: np.ndarray,
                    nrm: np.ndarray) -> None:
    """Link wrench about its origin as ``[n; f] = A φ_link`` (eq. 3.35), ``A [6, 10, S]``, from ``ω, ω̇, a [3, S]``
    (link frame, ``a`` with gravity folded in): ``f = m a + W mc``, ``n = mc × a + N_I ι`` with
    ``W = [ω̇×] + ωωᵀ − |ω|²·1`` and ``N_I ι = I ω̇ + ω × (I ω)``. Only the entries that are not structurally
    zero are written (``out`` must hold zeros there)."""
    np.multiply(w[:, None], w[None], out=ww)                                    # ω ωᵀ
    p01, p02, p12 = ww[0, 1], ww[0, 2], ww[1, 2]
    s0, s1, s2 = ww[0, 0], ww[1, 1], ww[2, 2]
    # n rows, mc columns: u·(mc × a) = mc·(a × u), so A[k, 1 + c] = [a×][c, k] (zero for k = c)
    np.copyto(out[0, 2], a[2])
    np.negative(a[1], out=out[0, 3])
    np.negative(a[2], out=out[1, 1])
    np.copyto(out[1, 3], a[0])
    np.copyto(out[2, 1], a[1])
    np.negative(a[0], out=out[2, 2])
    # n rows, I columns (xx, xy, xz, yy, yz, zz): N_I
    ni = out[:3, 4:]
    np.copyto(ni[0, 0], wd[0])
    np.copyto(ni[1, 0], p02)
    np.negative(p01, out=ni[2, 0])
    np.subtract(wd[1], p02, out=ni[0, 1])
    np.add(wd[0], p12, out=ni[1, 1])
    np.subtract(s0, s1, out=ni[2, 1])
    np.add(wd[2], p01, out=ni[0, 2])
    np.subtract(s2, s0, out=ni[1, 2])
    np.subtract(wd[0], p12, out=ni[2, 2])
    np.negative(p12, out=ni[0, 3])
    np.copyto(ni[1, 3], wd[1])
    np.copyto(ni[2, 3], p01)
    np.subtract(s1, s2, out=ni[0, 4])
    np.subtract(wd[2], p01, out=ni[1, 4])
    np.add(wd[1], p02, out=ni[2, 4])
    np.copyto(ni[0, 5], p12)
    np.negative(p02, out=ni[1, 5])
    np.copyto(ni[2, 5], wd[2])
    # f rows: m column a, mc columns W
    f = out[3:, :4]
    np.copyto(f[:, 0], a)
    np.add(s0, s1, out=nrm)
    nrm += s2
    for r in range(3):
        np.subtract(ww[r, r], nrm, out=f[r, 1 + r])
    np.subtract(p01, wd[2], out=f[0, 2])
    np.add(p02, wd[1], out=f[0, 3])
    np.add(p01, wd[2], out=f[1, 1])
    np.subtract(p12, wd[0], out=f[1, 3])
    np.subtract(p02, wd[1], out=f[2, 1])
    np.add(p12, wd[0], out=f[2, 2])


def _rigid_body_block(geo: RegressorGeometry, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                      out: np.ndarray, work: _Workspace) -> None:
    """Fill the 10 inertial columns of every link of ``out [n, 12n, S]`` for samples ``q, qd, qdd [n, S]``.

    Link ``j``'s wrench ``[n; f] = A_j φ_j`` (:func:`_link_regressor`) is projected on every joint ``i ≤ j``
    through joint ``i``'s unit screw ``[u; v]`` expressed in frame ``j``: row ``i`` of block ``j`` is
    ``[u; v]ᵀ A_j``. Joint ``j``'s own screw is the constant ``[k; 0]``; the screws of joints ``i < j`` move from
    frame ``j − 1`` to frame ``j`` as ``v ← v + u × o_j`` and a rotation.
    """
    n, n_s = q.shape
    cos, sin = np.cos(q), np.sin(q)
    mot, wrench, vec, tmp = work.motion, work.wrench, work.vec, work.tmp
    t_s = tmp[0]
    mot[0] = 0.0
    mot[0, :, 2] = -geo.gravity[:, None]                                        # base: ω = ω̇ = 0, a = −g
    for j in range(n):
        c, s, cross_o = cos[j], sin[j], geo.cross_offset[j]
        # motion of link j (eq. 3.40–3.42): acceleration of its origin in the parent frame, then ω, ω̇, a → frame j
        par, cur = mot[j % 2], mot[(j + 1) % 2]
        w, wd, acc = par[:, 0], par[:, 1], par[:, 2]
        if any(cross_o):
            for r, row in enumerate(cross_o):
                if row:
                    _accumulate(vec[r], t_s, [(coef, w[k], None) for coef, k in row])  # ω × o
            _apply(cross_o, wd, acc, t_s, add=True)                             # a += ω̇ × o
            for r, (p, q_) in enumerate(((1, 2), (2, 0), (0, 1))):              # a += ω × (ω × o)
                terms = [(1.0, w[p], vec[q_])] if cross_o[q_] else []           # skip (ω × o)_m ≡ 0
                terms += [(-1.0, w[q_], vec[p])] if cross_o[p] else []
                _accumulate(acc[r], t_s, terms, add=True)
        _to_child(geo.to_child[j], par, c, s, cur, tmp[:3], work.scratch[:, :3])
        w, wd, a = cur[:, 0], cur[:, 1], cur[:, 2]
        for r, row in enumerate(geo.cross_axis[j]):                             # ω̇ += (ω × k) q̇ + k q̈
            _accumulate(wd[r], t_s, [(coef, w[k], qd[j]) for coef, k in row], add=True)
        for coef, r in geo.axis[j]:
            _accumulate(w[r], t_s, [(coef, qd[j], None)], add=True)             # ω += k q̇
            _accumulate(wd[r], t_s, [(coef, qdd[j], None)], add=True)
        _link_regressor(w, wd, a, wrench, work.outer, t_s)
        blk = out[:, 12 * j:12 * j + 10]                                        # [n, 10, S]
        # joint j's own row: [k; 0]ᵀ A (its m column stays 0)
        _accumulate(blk[j, 1:], tmp[:9], [(coef, wrench[r, 1:], None) for coef, r in geo.axis[j]])
        scr = work.screw[j % 2]
        if j:
            # screws of joints < j: shift the moment to link j's origin (frame j − 1), then rotate into frame j
            old = work.screw[(j - 1) % 2][:, :, :j]
            _apply(cross_o, old[0], old[1], tmp[:j], add=True)                  # v += u × o
            _to_child(geo.to_child[j], old.transpose(1, 0, 2, 3), c, s, scr[:, :, :j].transpose(1, 0, 2, 3),
                      tmp[:2 * j].reshape(2, j, n_s), work.scratch[:, :2 * j].reshape(3, 2, j, n_s))
            screws = scr.reshape(6, n, n_s)[:, :j]                              # [u; v] of joints < j
            np.einsum("kis,kcs->ics", screws, wrench[:, :4], out=blk[:j, :4])          # m, mc
            np.einsum("kis,kcs->ics", screws[:3], wrench[:3, 4:], out=blk[:j, 4:])     # I (f has no I terms)
        scr[:, :, j] = 0.0                                                      # joint j's screw [k; 0]
        for coef, r in geo.axis[j]:
            scr[0, r, j] = coef


def regressor(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
              coulomb_velocity_scale: float | None = None, geometry: RegressorGeometry | None = None) -> np.ndarray:
    """``Y [N, n, 12n]`` with ``τ = Y φ`` (rigid body + friction) for samples ``q, qd, qdd [N, n]``.

    Returns a strided view of :func:`regressor_buffer` (see the module docstring for the layout and the parameter
    order); ``np.ascontiguousarray`` it if a ``[N·n, 12n]`` stacked matrix is needed.
    """
    return regressor_buffer(desc, q, qd, qdd, coulomb_velocity_scale, geometry).transpose(2, 0, 1)


def predict(buffer: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``τ [N, n] = Y φ`` from a regressor buffer ``[n, p, N]`` (a GEMV per joint on its nonzero block)."""
    n = buffer.shape[0]
    per = PARAMS_PER_JOINT
    return np.stack([phi[per * i:] @ buffer[i, per * i:] for i in range(n)], axis=1)
