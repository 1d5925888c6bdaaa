"""The one friction law of the project: the smooth sign of q̇ and the viscous + Coulomb torque.

``τ_f = F_v q̇ + F_c sgn_s(q̇)`` [N·m] with ``sgn_s(q̇) = tanh(q̇ / v_s)``; ``v_s`` [rad/s] is the smoothing velocity
(``v_s = 0`` is the limit, the exact ``sign``, kept for identified models saved with it).

Every stage evaluates friction through these functions — the twin's joint drive (per step, on ``q̇ [n]``), the
effects (``viscous_coulomb``, ``stribeck``, ``friction_warmup``, the motor's friction), the diagnosis' model, its
candidates and features, the identification regressor, the learning backbone and the estimator (batches
``[N, n]``). The per-step and the batch forms are the same code: numpy broadcasting over any leading shape; the twin's
C++ drive evaluates the same code traced once on symbolic velocities (``pydrake.symbolic``).

**One smoothing.** :data:`SMOOTH_VELOCITY` is the library default of ``v_s``; a call with ``smooth_velocity=None``
reads it at call time, and the friction effects take it as their ``smooth_velocity`` setting's default when they are
built, so a change here changes the twin, the diagnosis and the estimator alike. A robot description's friction
(``friction.viscous`` / ``friction.coulomb``) is this law at this default. An effect's ``smooth_velocity`` setting
overrides it for that effect only.

Why 0.05 rad/s: it is the law the twin — the robot the project treats as real — already ran (the calibrated
``iiwa14_twin`` and the gap benchmark's twins, chosen there for the margin of explicit friction at 1 ms, whose slope
at rest ``F_v + F_c / v_s`` is :func:`slope_at_rest`), so a model of the twin (diagnosis, estimator, identification)
now uses the law the data came from instead of ``sign`` or ``tanh(q̇/0.02)``. It is also about the band (≈ 3 °/s)
where a velocity differentiated from a quantised encoder and low-passed is too unreliable to give the direction of
motion, so the exact sign there is noise rather than information.

**Load-dependent Coulomb friction** (:func:`load_coulomb`): ``F_c = F_c0 + k |τ_load|`` — the Coulomb level of a
harmonic drive grows with the torque it transmits (tooth and wave-generator bearing loads: Hamon & Gautier; Wolf &
Iskandar), ``τ_f = (F_c0 + k |τ_load|) sgn_s(q̇)`` with the same smooth sign. **The load is the link-side joint
torque** τ_J the joint's gear transmits (what a joint-torque sensor measures; the rigid-body torque plus the link
friction), per joint: for a coupled wrist too it is the joint's own output torque, not the shared motor's torque
(the friction is the joint's gear's, on the joint velocity). Each stage takes the load it has: the twin's drive the
torque it transmits in the step (the commanded joint torque, :func:`load_from_net` recovers it from the logged net
actuation), the diagnosis the modelled link torque, the identification the measured τ (``identify --load-friction``),
the benchmark's offline model the rigid-body torque.

This module is in the core layer and imports numpy only: effects, identification and learning (layer 2, independent
of each other) all call it.
"""
from __future__ import annotations

import numpy as np

__all__ = ["SMOOTH_VELOCITY", "smooth_sign", "viscous_coulomb", "load_coulomb", "load_from_net", "slope_at_rest",
           "smoothing"]

SMOOTH_VELOCITY = 0.05
"""Library default smoothing velocity ``v_s`` [rad/s] of the Coulomb sign (see the module docstring)."""


def smoothing(smooth_velocity: float | np.ndarray | None = None) -> float | np.ndarray:
    """``smooth_velocity`` [rad/s], or the library default :data:`SMOOTH_VELOCITY` when ``None`` (read now)."""
    return SMOOTH_VELOCITY if smooth_velocity is None else smooth_velocity


def smooth_sign(qd: np.ndarray, smooth_velocity: float | np.ndarray | None = None) -> np.ndarray:
    """``tanh(q̇ / v_s)`` [-] for joint velocities ``qd`` [rad/s] of any shape (``[n]`` per step, ``[N, n]`` batch);
    ``v_s`` [rad/s] a scalar or per-joint ``[n]`` > 0 (``None``: the library default). A scalar ``v_s = 0`` gives
    the exact ``sign(q̇)``, the law's limit."""
    v = SMOOTH_VELOCITY if smooth_velocity is None else smooth_velocity       # (inlined: a per-step hot path)
    if not isinstance(v, np.ndarray) and v == 0.0:
        return np.sign(qd)
    return np.tanh(np.divide(qd, v))


def viscous_coulomb(qd: np.ndarray, viscous: float | np.ndarray, coulomb: float | np.ndarray,
                    smooth_velocity: float | np.ndarray | None = None) -> np.ndarray:
    """Friction torque ``F_v q̇ + F_c tanh(q̇ / v_s)`` [N·m] (dissipative: ``τ_f q̇ ≥ 0``) for velocities ``qd``
    [rad/s] of any shape, viscous ``F_v`` [N·m·s/rad] and Coulomb ``F_c`` [N·m] scalars or per joint ``[n]``. ``qd``
    may hold ``pydrake.symbolic`` variables (an object array): the result is then the law as symbolic expressions,
    which the twin's drive evaluates in C++ (:class:`proprio.systems.joint_drive.FrictionDrive`)."""
    qd = np.asarray(qd)
    if qd.dtype != object:               # an object array holds Drake symbolic Expressions (a System traced from it)
        qd = qd.astype(float, copy=False)
    return viscous * qd + coulomb * smooth_sign(qd, smooth_velocity)


def slope_at_rest(viscous: float | np.ndarray, coulomb: float | np.ndarray,
                  smooth_velocity: float | np.ndarray | None = None) -> np.ndarray:
    """``∂τ_f/∂q̇`` at ``q̇ = 0`` [N·m·s/rad]: ``F_v + F_c / v_s``, the steepest slope of the law (what explicit
    integration of the friction must resolve)."""
    return np.asarray(viscous + np.asarray(coulomb) / smoothing(smooth_velocity), dtype=float)


def load_coulomb(qd: np.ndarray, coulomb: float | np.ndarray, load_gain: float | np.ndarray, tau_load: np.ndarray,
                 smooth_velocity: float | np.ndarray | None = None) -> np.ndarray:
    """Load-dependent Coulomb friction ``(F_c0 + k |τ_load|) tanh(q̇ / v_s)`` [N·m] (module docstring) for velocities
    ``qd`` [rad/s] and link-side joint torques ``tau_load`` [N·m] of the same shape (``[n]`` or ``[N, n]``); ``F_c0``
    [N·m] and the load gain ``k`` [-] scalars or per joint ``[n]``. Dissipative (``τ_f q̇ ≥ 0``)."""
    return (coulomb + load_gain * np.abs(tau_load)) * smooth_sign(np.asarray(qd, dtype=float), smooth_velocity)


def load_from_net(net: np.ndarray, sign: np.ndarray, load_gain: np.ndarray) -> np.ndarray:
    """The transmitted torque ``u`` [N·m] whose load-dependent friction leaves ``net``: the root of
    ``u − k |u| s = net`` for the smooth sign ``s`` (|s| ≤ 1) and the summed load gain ``k < 1`` [-] (``net`` [N·m]
    holds everything else: ``u − τ_f,other − F_c0 s`` as the caller has it). The left side rises monotonically in
    ``u`` and is 0 at 0, so ``u`` has the sign of ``net``: ``u = net / (1 − k s sign(net))`` — the twin's τ_J from its
    logged net actuation, exact."""
    net = np.asarray(net, dtype=float)
    return net / (1.0 - load_gain * sign * np.sign(net))
