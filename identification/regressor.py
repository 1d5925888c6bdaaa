"""Newton–Euler inertial-parameter regressor ``τ = Y(q, q̇, q̈) φ`` (thesis eq. 3.35–3.49), batched over samples.

Standard parameter vector ``φ ∈ ℝ^{12n}``: per joint/link ``j`` a block of 12 numbers, in this order::

    [m, m·cx, m·cy, m·cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz, Fv, Fc]

* ``m`` [kg]; ``m·c`` [kg·m] the first mass moment, ``c`` the CoM in the *link frame* of ``desc`` (URDF semantics:
  the joint frame rotated by ``q_j``);
* ``I`` [kg·m²] the rotational inertia **about the link-frame origin** (not the CoM), link-frame axes, tensor entries
  (``Ixy`` is the matrix element, i.e. ``−∫xy dm``);
* ``Fv`` [N·m·s/rad] viscous and ``Fc`` [N·m] Coulomb friction of joint ``j``: ``τ_f = Fv q̇ + Fc sgn(q̇)``, where
  ``sgn`` is ``np.sign`` (``coulomb_velocity_scale = 0``, the default) or the smooth ``tanh(q̇ / scale)``.

The recursion is the thesis' Algorithm 4.7 in link frames: motion (ω, ω̇, linear acceleration of the origin with
``−g`` folded in) is propagated outwards, and instead of propagating wrenches inwards, every joint ``i ≤ j`` is
projected onto link ``j``'s wrench through joint ``i``'s unit screw expressed in frame ``j`` (axis ``u_ij``, moment
``v_ij = u_ij × (o_j − o_i)``): ``τ_i ← u_ij · n_j + v_ij · f_j`` (eq. 3.43–3.45 collapsed to one projection).

Memory layout: all internal arrays are component-major with the sample axis last and contiguous (``[3, N]``), so
every operation is a long vectorised loop and every rotation is one small GEMM. :func:`regressor` returns
``Y [N, n, 12n]`` as a strided *view* of a ``[n, 12n, N]`` buffer (``Y.base``): estimators that form normal
equations use the buffer directly (:func:`regressor_buffer`), each joint row block ``[12n, N]`` being contiguous.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from proprio.description import Link, RobotDescription, rpy_to_matrix

__all__ = ["PARAMS_PER_JOINT", "PARAMETER_KEYS", "parameter_names", "standard_parameters", "parameters_to_links",
           "friction_from_parameters", "regressor", "regressor_buffer", "predict", "RegressorGeometry",
           "regressor_geometry"]

PARAMETER_KEYS = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz", "Fv", "Fc")
PARAMS_PER_JOINT = len(PARAMETER_KEYS)


def parameter_names(n: int) -> list[str]:
    """Names of the standard parameters, e.g. ``"Izz3"`` (1-based joint/link index, as in the thesis)."""
    return [f"{k}{j + 1}" for j in range(n) for k in PARAMETER_KEYS]


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def standard_parameters(desc: RobotDescription) -> np.ndarray:
    """The standard parameter vector ``φ [12n]`` of ``desc`` (order in the module docstring). Missing friction
    counts as zero."""
    out = np.zeros(PARAMS_PER_JOINT * desc.n)
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
    if phi.shape != (PARAMS_PER_JOINT * template.n,):
        raise ValueError(f"parameters_to_links: phi must have {PARAMS_PER_JOINT * template.n} entries, "
                         f"got {phi.shape}")
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
    p = np.asarray(phi, dtype=float).reshape(n, PARAMS_PER_JOINT)
    return tuple(float(x) for x in p[:, 10]), tuple(float(x) for x in p[:, 11])


@dataclass(frozen=True)
class RegressorGeometry:
    """Constant kinematics of the chain in the form the regressor uses."""
    rot: np.ndarray        # [n, 9, 3] stacked [(I−kkᵀ)R_oᵀ; [k×]R_oᵀ; kkᵀR_oᵀ]: child ← parent is c·A1 − s·A2 + A3
    offset: np.ndarray     # [n, 3] joint origin in the parent link frame [m]
    axis: np.ndarray       # [n, 3] unit joint axis in the joint (= child link) frame
    gravity: np.ndarray    # [3] gravity in the base frame [m/s²]


def regressor_geometry(desc: RobotDescription) -> RegressorGeometry:
    """Precompute the constant rotations of ``desc`` (Rodrigues split so that ``R(q)ᵀ x`` is one 9×3 GEMM)."""
    rots, offsets, axes = [], [], []
    for jt in desc.joints:
        k = np.asarray(jt.axis, dtype=float)
        k = k / np.linalg.norm(k)
        r_o_t = rpy_to_matrix(jt.origin_rpy).T
        kk = np.outer(k, k)
        rots.append(np.vstack([(np.eye(3) - kk) @ r_o_t, _skew(k) @ r_o_t, kk @ r_o_t]))
        offsets.append(np.asarray(jt.origin_xyz, dtype=float))
        axes.append(k)
    g_base = rpy_to_matrix(desc.world_to_base_rpy).T @ np.asarray(desc.gravity, dtype=float)
    return RegressorGeometry(np.array(rots), np.array(offsets), np.array(axes), g_base)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the leading axis of component-major arrays ``[3, ...]`` (broadcasting the rest)."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _fma(x: np.ndarray, y: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> None:
    """``out += x * y`` without allocating (``tmp`` is scratch of ``out``'s shape)."""
    np.multiply(x, y, out=tmp)
    out += tmp


def _dot3(x: np.ndarray, y: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> None:
    """``out = Σ_k x[k] y[k]`` over the leading component axis, written in place."""
    np.multiply(x[0], y[0], out=out)
    _fma(x[1], y[1], out, tmp)
    _fma(x[2], y[2], out, tmp)


def _to_child(rot: np.ndarray, x: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Express parent-frame vectors ``x [3, ..., N]`` in the child frame: ``R_axis(q)ᵀ R_oᵀ x``."""
    y = np.einsum("ij,jm->im", rot, x.reshape(3, -1)).reshape((9,) + x.shape[1:])   # no BLAS threads for 9×3
    return c * y[0:3] - s * y[3:6] + y[6:9]


def _as_samples(name: str, x: np.ndarray, n: int) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[None]
    if x.ndim != 2 or x.shape[1] != n:
        raise ValueError(f"regressor: {name} must be [N,{n}], got shape {x.shape}")
    return x


CHUNK = 4096  # samples per pass: keeps every temporary of the inner loop in cache


def regressor_buffer(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     coulomb_velocity_scale: float = 0.0,
                     geometry: RegressorGeometry | None = None) -> np.ndarray:
    """The regressor in its native layout ``B [n, 12n, N]``: ``τ_i(s) = Σ_c B[i, c, s] φ_c``.

    Row ``i`` is nonzero only in columns ``12i:`` (joint ``i`` carries links ``i..n−1``), so ``B[i, 12i:]`` is the
    contiguous block estimators multiply with. Inputs ``q, qd, qdd [N, n]`` in rad, rad/s, rad/s².
    """
    geo = geometry or regressor_geometry(desc)
    n = desc.n
    q, qd, qdd = (np.ascontiguousarray(_as_samples(k, v, n).T) for k, v in (("q", q), ("qd", qd), ("qdd", qdd)))
    if not q.shape == qd.shape == qdd.shape:
        raise ValueError(f"regressor: q, qd, qdd must have the same shape, got {q.shape}, {qd.shape}, {qdd.shape}")
    n_s = q.shape[1]
    out = np.zeros((n, PARAMS_PER_JOINT * n, n_s))
    for s0 in range(0, n_s, CHUNK):
        sl = slice(s0, min(s0 + CHUNK, n_s))
        _rigid_body_block(geo, q[:, sl], qd[:, sl], qdd[:, sl], out[:, :, sl])
    for j in range(n):
        out[j, 12 * j + 10] = qd[j]
        out[j, 12 * j + 11] = (np.sign(qd[j]) if coulomb_velocity_scale == 0.0
                               else np.tanh(qd[j] / coulomb_velocity_scale))
    return out


def _rigid_body_block(geo: RegressorGeometry, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                      out: np.ndarray) -> None:
    """Fill the 10 inertial columns of every link of ``out [n, 12n, S]`` for samples ``q, qd, qdd [n, S]``."""
    n, n_s = q.shape
    cos, sin = np.cos(q), np.sin(q)
    w = np.zeros((3, n_s))                                   # ω of the parent, parent frame
    wd = np.zeros((3, n_s))                                  # ω̇
    acc = np.repeat(-geo.gravity[:, None], n_s, axis=1)     # linear acceleration of the origin minus g
    u = np.zeros((3, 0, n_s))                                # screws of joints < j: axis, moment about the origin
    v = np.zeros((3, 0, n_s))
    for j in range(n):
        s_j, k = geo.offset[j], geo.axis[j]
        c_j, s_jn = cos[j], sin[j]
        # motion of link j (eq. 3.40–3.42): origin acceleration in the parent frame, then rotate all at once
        acc_par = acc + _cross(wd, s_j[:, None]) + _cross(w, _cross(w, s_j[:, None]))
        w_c, wd_c, acc = _to_child(geo.rot[j], np.stack([w, wd, acc_par], axis=1), c_j, s_jn).transpose(1, 0, 2)
        k_col = k[:, None]
        w = w_c + k_col * qd[j]
        wd = wd_c + _cross(w_c, k_col) * qd[j] + k_col * qdd[j]
        # screws of joints < j move to frame j; joint j's own screw is (k, 0)
        if j:
            v = v + _cross(u, s_j[:, None, None])
            uv = _to_child(geo.rot[j], np.concatenate([u, v], axis=1), c_j, s_jn)
            u, v = uv[:, :j], uv[:, j:]
        u = np.concatenate([u, np.broadcast_to(k[:, None, None], (3, 1, n_s))], axis=1)
        v = np.concatenate([v, np.zeros((3, 1, n_s))], axis=1)
        # link j's wrench about its origin is linear in its 10 parameters (eq. 3.35); project on every joint i ≤ j:
        # τ_i = u·n + v·f with f = m a + ω̇×mc + ω×(ω×mc), n = I ω̇ + ω×(I ω) + mc×a, i.e.
        # m: v·a;  mc: vᵀW + a×u with W = [ω̇×] + ωωᵀ − |ω|²·1;  I_ab: u_a ω̇_b + (u×ω)_a ω_b (+ a↔b)
        wm = np.einsum("as,bs->abs", w, w)
        wm -= np.einsum("aas->s", wm) * np.eye(3)[:, :, None]
        wm[0, 1] -= wd[2]
        wm[0, 2] += wd[1]
        wm[1, 0] += wd[2]
        wm[1, 2] -= wd[0]
        wm[2, 0] -= wd[1]
        wm[2, 1] += wd[0]
        blk = out[:j + 1, 12 * j:12 * j + 10]                 # [j+1, 10, S] view
        tmp = np.empty_like(v[0])
        _dot3(v, acc, blk[:, 0], tmp)
        a_u = _cross(acc[:, None], u)
        for c in range(3):
            _dot3(v, wm[:, c], blk[:, 1 + c], tmp)
            blk[:, 1 + c] += a_u[c]
        uw = _cross(u, w[:, None])
        for col, (a_, b_) in zip(range(4, 10), ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
            out_c = blk[:, col]
            np.multiply(u[a_], wd[b_], out=out_c)
            _fma(uw[a_], w[b_], out_c, tmp)
            if a_ != b_:
                _fma(u[b_], wd[a_], out_c, tmp)
                _fma(uw[b_], w[a_], out_c, tmp)


def regressor(desc: RobotDescription, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
              coulomb_velocity_scale: float = 0.0, geometry: RegressorGeometry | None = None) -> np.ndarray:
    """``Y [N, n, 12n]`` with ``τ = Y φ`` (rigid body + friction) for samples ``q, qd, qdd [N, n]``.

    Returns a strided view of :func:`regressor_buffer` (see the module docstring for the layout and the parameter
    order); ``np.ascontiguousarray`` it if a ``[N·n, 12n]`` stacked matrix is needed.
    """
    return regressor_buffer(desc, q, qd, qdd, coulomb_velocity_scale, geometry).transpose(2, 0, 1)


def predict(buffer: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``τ [N, n] = Y φ`` from a regressor buffer ``[n, p, N]`` (a GEMV per joint on its nonzero block)."""
    n = buffer.shape[0]
    per = buffer.shape[1] // n
    return np.stack([phi[per * i:] @ buffer[i, per * i:] for i in range(n)], axis=1)
