"""The joint-effect library: one class per effect that spoils a torque-sensing joint, each able to *simulate* its
additive contribution to the measured link-side torque τ_J (vectorised over samples and joints) and to be *fitted*
(flat parameter vector + bounds for nonlinear least squares, a regressor for the linear ones).

Convention (DESIGN.md, thesis eq. 3.5–3.6): ``τ_J = τ_rbd(q, q̇, q̈) + Σ visible contributions − Jᵀ f_ext``. Every
effect's :meth:`JointEffect.torque` returns its ``[N, n]`` contribution in N·m; motor-side effects contribute zero to
τ_J (they are hidden behind the sensor and show up only through the motion).

Effects, their place, and where their twin magnitudes come from (``proprio/configs/iiwa14_twin.yaml``):

============================ ======= =============================================================================
effect (YAML key)             place   model / calibration source
============================ ======= =============================================================================
``viscous_coulomb``           link    ``F_v q̇ + F_c tanh(q̇/v_s)``; identified iiwa14 set (Coulomb 0.03–0.32 N·m,
                                      viscous 0.10–0.37 N·m·s/rad, ``proprio/robots/iiwa14_identified.yaml``)
``stribeck``                  link    extra static friction ``F_s exp(−(q̇/v_st)²) tanh(q̇/v_s)``; low-speed
                                      friction of harmonic drives (not in the thesis; off in the calibrated twin)
``hysteresis``                sensor  Dahl law in the reversal-travel domain, saturating ≈95 % after 6° (§2.1,
                                      Fig. 2.5); amplitude scaled with load on joints 2/4
``lost_motion``               sensor  a ≈1° window after each reversal in which the direction-dependent torque
                                      has not flipped yet (§4 intro, "absent changes ... of approximately 1°")
``ripple``                    sensor  harmonic-drive ripple ``A sin(h·N·q + φ)``: frequency ``h·N·q̇/2π`` follows
                                      joint speed (§6); amplitude chosen so raw τ is visibly noisy at 10 % speed
``sensor_offset_gain``        sensor  ``g·τ + o``; offsets 0.1–0.9 N·m (DESIGN.md), gain error ≈1 %
``torque_noise``              sensor  white Gaussian noise σ; "significant torque noise" at 10 % speed (Fig. 2.5)
``encoder_noise``             sensor  position noise + quantisation of q (no torque contribution)
(:class:`Motor`)              motor   reflected motor inertia B and motor friction, hidden behind the sensor;
                                      the twin's ``drive`` block, not an ``EFFECTS`` entry (nothing to fit in τ_J)
``elasticity``                motor   series elastic drive (K, D) with the motor's state, simulated by
                                      ``proprio.systems.joint_drive``; zero direct contribution to τ_J
============================ ======= =============================================================================

Hysteresis and lost motion share one state, the *reversal travel* ``r`` (signed joint travel since the last
direction reversal, :func:`reversal_travel`) — the quantity behind the thesis' feature ``r`` (§4.2), which the learning
stack encodes causally with a position deadband and ±10° clipping in :mod:`proprio.learning.features`. Reversals are detected
with a velocity deadband (Schmitt trigger on q̇) so that noise around standstill does not create spurious reversals;
the travel is measured from the extremum of q reached before the reversal. Stateful effects are evaluated per
segment between reversals; the values carried across segments follow an affine recursion that is solved with a
vectorised prefix scan (no per-sample Python loop). The same laws run sample by sample, with the reversal state as
Drake discrete state, in :class:`proprio.systems.sensors.TorqueSensorSystem` (tested equal to 1e-9).
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "MotionSignals", "ReversalTravel", "motion_direction", "reversal_travel", "JointEffect", "EffectConfigError",
    "ViscousCoulomb", "Stribeck", "Hysteresis", "LostMotion", "Ripple", "SensorOffsetGain", "TorqueNoise",
    "EncoderNoise", "Motor", "Elasticity", "EFFECTS", "make_effects",
]


class EffectConfigError(ValueError):
    """A joint-effect configuration is invalid; the message names the effect and the field."""


# ------------------------------------------------------------------------------------------------------------------
# signals and the reversal-travel state
# ------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MotionSignals:
    """Link-side motion that effects are functions of (SI units, shapes ``[N]`` / ``[N, n]``).

    ``tau`` (optional) is the link-side torque the sensor sees before the effect is applied: the gain error scales
    it, and load-dependent amplitudes (``load_gain``) grow with ``|tau|``. The twin passes its true τ_J; a fit on
    measured data may pass the measured or modelled τ.
    """
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.q.ndim != 2 or self.qd.shape != self.q.shape or self.qdd.shape != self.q.shape:
            raise ValueError(f"MotionSignals: q, qd, qdd must all be [N, n], got {self.q.shape}, {self.qd.shape}, "
                             f"{self.qdd.shape}")
        if self.t.shape != (self.q.shape[0],):
            raise ValueError(f"MotionSignals: t must be [N] = [{self.q.shape[0]}], got {self.t.shape}")
        if self.tau is not None and self.tau.shape != self.q.shape:
            raise ValueError(f"MotionSignals: tau must be {self.q.shape}, got {self.tau.shape}")

    @property
    def n(self) -> int:
        return int(self.q.shape[1])

    @classmethod
    def from_recording(cls, rec: Any, tau: np.ndarray | None = None) -> "MotionSignals":
        """Signals of a :class:`proprio.recording.Recording`: its ``qd``/``qdd`` if present, else central differences
        (``np.gradient``, second order inside). ``tau`` defaults to the recording's measured torque."""
        t = np.asarray(rec.t, dtype=float)
        q = np.asarray(rec.q, dtype=float)
        qd = np.asarray(rec.qd, dtype=float) if rec.qd is not None else np.gradient(q, t, axis=0)
        qdd = np.asarray(rec.qdd, dtype=float) if rec.qdd is not None else np.gradient(qd, t, axis=0)
        return cls(t=t, q=q, qd=qd, qdd=qdd, tau=np.asarray(rec.tau if tau is None else tau, dtype=float))

    def with_tau(self, tau: np.ndarray | None) -> "MotionSignals":
        return MotionSignals(self.t, self.q, self.qd, self.qdd, tau)


@dataclass(frozen=True)
class ReversalTravel:
    """Per-joint reversal segmentation of a motion.

    ``r [N,n]`` rad: signed travel since the last direction reversal (``q − anchor``); ``direction [N,n]`` ∈ {−1, 0,
    +1}: the current direction (0 until the joint first moves); ``segment [N,n]``: segment
    index per joint (0 = from the start to the first reversal). Per joint ``j``: ``starts[j]`` first sample of each
    segment, ``anchors[j]`` the position each segment's travel is measured from (q[0] for segment 0, else the
    extremum reached in the previous segment), ``seg_direction[j]``.
    """
    r: np.ndarray
    direction: np.ndarray
    segment: np.ndarray
    starts: tuple[np.ndarray, ...]
    anchors: tuple[np.ndarray, ...]
    seg_direction: tuple[np.ndarray, ...]


def motion_direction(qd: np.ndarray, reversal_velocity: float | np.ndarray) -> np.ndarray:
    """Direction of motion per joint, ``[N,n]`` ∈ {−1, 0, +1}: +1 while ``q̇ > reversal_velocity``, −1 while
    ``q̇ < −reversal_velocity``, and the last such value inside the band (a Schmitt trigger, so noise around a
    standstill does not flip it); 0 until the joint first leaves the band. ``reversal_velocity`` [rad/s], scalar or
    per joint."""
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    eps = np.broadcast_to(np.asarray(reversal_velocity, dtype=float), (qd.shape[1],))
    raw = np.where(qd > eps, 1.0, np.where(qd < -eps, -1.0, 0.0))
    last = np.maximum.accumulate(np.where(raw != 0, np.arange(qd.shape[0])[:, None], 0), axis=0)
    return np.take_along_axis(raw, last, axis=0)                          # forward-filled direction


def reversal_travel(q: np.ndarray, qd: np.ndarray, reversal_velocity: float | np.ndarray = 2e-3) -> ReversalTravel:
    """Segment ``q [N,n]`` at direction reversals and return the signed travel since the last one.

    A joint's direction switches only when ``|q̇|`` exceeds ``reversal_velocity`` [rad/s] with the opposite sign
    (a deadband: noise around standstill keeps the previous direction). The travel after a reversal is measured
    from the extremum of q in the segment that ended, so a late detection does not shift r.
    """
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    n_s, n = q.shape
    held = motion_direction(qd, reversal_velocity)
    r = np.empty_like(q)
    direction = np.empty((n_s, n))
    segment = np.empty((n_s, n), dtype=np.int64)
    starts, anchors, seg_dirs = [], [], []
    for j in range(n):                                                    # loop over joints only
        d = held[:, j]
        flip = np.zeros(n_s, dtype=bool)
        flip[1:] = (d[1:] != d[:-1]) & (d[:-1] != 0)
        seg = np.cumsum(flip)
        st = np.concatenate([[0], np.flatnonzero(flip)])
        ends = np.concatenate([st[1:] - 1, [n_s - 1]])
        sd = d[ends]                                                      # direction of each segment
        hi = np.maximum.reduceat(q[:, j], st)
        lo = np.minimum.reduceat(q[:, j], st)
        anc = np.concatenate([[q[0, j]], np.where(sd[:-1] > 0, hi[:-1], lo[:-1])])
        r[:, j] = q[:, j] - anc[seg]
        direction[:, j] = d
        segment[:, j] = seg
        starts.append(st)
        anchors.append(anc)
        seg_dirs.append(sd)
    return ReversalTravel(r, direction, segment, tuple(starts), tuple(anchors), tuple(seg_dirs))


def affine_scan(a: np.ndarray, b: np.ndarray, x0: float) -> np.ndarray:
    """Solve ``x[s+1] = a[s]·x[s] + b[s]`` for all s at once (Hillis–Steele prefix scan of affine maps, log₂ S
    vectorised passes; stable for |a| ≤ 1). Returns ``x[0..S]``."""
    big_a, big_b = np.asarray(a, dtype=float).copy(), np.asarray(b, dtype=float).copy()
    shift = 1
    while shift < big_a.size:
        new_a, new_b = big_a.copy(), big_b.copy()
        new_a[shift:] = big_a[shift:] * big_a[:-shift]
        new_b[shift:] = big_a[shift:] * big_b[:-shift] + big_b[shift:]
        big_a, big_b = new_a, new_b
        shift *= 2
    return np.concatenate([[x0], big_a * x0 + big_b])


# ------------------------------------------------------------------------------------------------------------------
# the base class
# ------------------------------------------------------------------------------------------------------------------
class JointEffect(ABC):
    """One joint effect with per-joint parameter arrays (shape ``[n]``).

    Subclasses declare ``parameters`` (fitted: name → (default, lower, upper); these form :meth:`vector`) and
    ``settings`` (fixed per-joint hyper-parameters: name → (default, lower, upper)). A lower bound of ``0.0`` is
    inclusive; where a value must be strictly positive the lower bound is a tiny positive number.
    """
    name: ClassVar[str]
    place: ClassVar[str]                       # "motor" | "link" | "sensor"
    linear: ClassVar[bool]
    parameters: ClassVar[dict[str, tuple[float, float, float]]] = {}
    settings: ClassVar[dict[str, tuple[float, float, float]]] = {}

    def __init__(self, n: int, **params: Any) -> None:
        self.n = int(n)
        spec = {**self.parameters, **self.settings}
        unknown = sorted(set(params) - set(spec))
        if unknown:
            raise EffectConfigError(f"{self.name}: unknown field(s) {unknown}; valid fields: {sorted(spec)}")
        self._values: dict[str, np.ndarray] = {}
        for key, (default, lower, upper) in spec.items():
            arr = self._per_joint(key, params.get(key, default))
            if np.any(arr < lower) or np.any(arr > upper):
                bad = arr[(arr < lower) | (arr > upper)][0]
                raise EffectConfigError(f"{self.name}.{key} = {bad:g} is outside [{lower:g}, {upper:g}]")
            self._values[key] = arr

    def _per_joint(self, key: str, value: Any) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise EffectConfigError(f"{self.name}.{key} must be a number or a list of {self.n} numbers") from exc
        if arr.ndim == 0:
            arr = np.full(self.n, float(arr))
        if arr.shape != (self.n,):
            raise EffectConfigError(f"{self.name}.{key} must be a number or a list of {self.n} numbers, got shape "
                                    f"{list(arr.shape)}")
        if not np.all(np.isfinite(arr)):
            raise EffectConfigError(f"{self.name}.{key} must be finite")
        return arr

    def __getattr__(self, key: str) -> np.ndarray:
        values = self.__dict__.get("_values")
        if values is not None and key in values:
            return values[key]
        raise AttributeError(key)

    def __repr__(self) -> str:
        body = ", ".join(f"{k}={np.array2string(v, precision=4)}" for k, v in self._values.items())
        return f"{type(self).__name__}({body})"

    @classmethod
    def from_config(cls, block: dict | None, n: int) -> "JointEffect":
        """Build from a YAML block; scalars broadcast to ``n`` joints, keys ending ``_deg`` are converted to rad."""
        if block is not None and not isinstance(block, dict):
            raise EffectConfigError(f"{cls.name}: the YAML block must be a mapping of fields, got {block!r}")
        params = {}
        for key, value in (block or {}).items():
            if key.endswith("_deg"):
                key, value = key[:-4], np.radians(np.asarray(value, dtype=float))
            params[key] = value
        return cls(n, **params)

    def params(self) -> dict[str, np.ndarray]:
        """All per-joint parameters and settings (copies)."""
        return {k: v.copy() for k, v in self._values.items()}

    def vector(self) -> np.ndarray:
        """The fitted parameters, concatenated in ``parameters`` order (each ``[n]``)."""
        if not self.parameters:
            return np.zeros(0)
        return np.concatenate([self._values[k] for k in self.parameters])

    def with_vector(self, theta: np.ndarray) -> "JointEffect":
        """A copy with the fitted parameters replaced by ``theta`` (settings unchanged)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (len(self.parameters) * self.n,):
            raise ValueError(f"{self.name}: theta must have {len(self.parameters) * self.n} entries, got {theta.shape}")
        new = {k: theta[i * self.n:(i + 1) * self.n] for i, k in enumerate(self.parameters)}
        settings = {k: self._values[k] for k in self.settings}
        return type(self)(self.n, **new, **settings)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of :meth:`vector` (for ``scipy.optimize.least_squares``)."""
        lo = np.concatenate([np.full(self.n, spec[1]) for spec in self.parameters.values()] or [np.zeros(0)])
        hi = np.concatenate([np.full(self.n, spec[2]) for spec in self.parameters.values()] or [np.zeros(0)])
        return lo, hi

    @abstractmethod
    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        """Additive contribution to the measured τ_J, ``[N, n]`` N·m (``rng``: seeded generator for random
        effects)."""

    def regressor(self, s: MotionSignals) -> np.ndarray:
        """``[N, n, len(vector())]`` with ``torque == einsum("tnp,p->tn", regressor, vector())`` (linear effects)."""
        raise NotImplementedError(f"{self.name} is nonlinear in its parameters; fit it with least squares on "
                                  "vector()/with_vector()/bounds()")

    def _check_n(self, s: MotionSignals) -> None:
        if s.n != self.n:
            raise ValueError(f"{self.name}: configured for {self.n} joints, signals have {s.n}")

    def _load_scale(self, s: MotionSignals, base: np.ndarray, load_gain: np.ndarray) -> np.ndarray:
        """``base + load_gain·|τ|`` per sample (``[N,n]``); needs ``s.tau`` when any load gain is non-zero."""
        if not np.any(load_gain):
            return np.broadcast_to(base, s.q.shape)
        if s.tau is None:
            raise ValueError(f"{self.name}: load_gain is set, so MotionSignals.tau (link-side torque) is required")
        return base + load_gain * np.abs(s.tau)


def _diagonal_regressor(columns: list[np.ndarray]) -> np.ndarray:
    """Stack per-joint columns ``[N,n]`` (one per parameter block) into ``[N, n, len(columns)·n]``."""
    n_s, n = columns[0].shape
    reg = np.zeros((n_s, n, len(columns) * n))
    jj = np.arange(n)
    for b, col in enumerate(columns):
        reg[:, jj, b * n + jj] = col
    return reg


# ------------------------------------------------------------------------------------------------------------------
# link-side friction (visible in τ_J, dissipative)
# ------------------------------------------------------------------------------------------------------------------
_INF = math.inf
_TINY = 1e-9


class ViscousCoulomb(JointEffect):
    """Link-side friction ``τ_f = F_v q̇ + F_c tanh(q̇ / v_s)`` [N·m] (smooth sign, so ``τ_f q̇ ≥ 0`` always).

    Parameters ``viscous`` F_v [N·m·s/rad], ``coulomb`` F_c [N·m]; setting ``smooth_velocity`` v_s [rad/s].
    """
    name = "viscous_coulomb"
    place = "link"
    linear = True
    parameters = {"viscous": (0.0, 0.0, _INF), "coulomb": (0.0, 0.0, _INF)}
    settings = {"smooth_velocity": (0.02, _TINY, _INF)}

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """τ_f [N·m] for joint velocities ``qd`` (``[n]`` or ``[N,n]``)."""
        v = self._values
        return v["viscous"] * qd + v["coulomb"] * np.tanh(qd / v["smooth_velocity"])

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return _diagonal_regressor([s.qd, np.tanh(s.qd / self.smooth_velocity)])


class Stribeck(JointEffect):
    """Extra static friction that fades with speed: ``F_s exp(−(q̇/v_st)²) tanh(q̇/v_s)`` [N·m] (dissipative).

    Parameters ``static`` F_s [N·m] (breakaway minus Coulomb level), ``stribeck_velocity`` v_st [rad/s]; setting
    ``smooth_velocity`` v_s [rad/s]. Add it to ``viscous_coulomb`` for the full Stribeck curve.
    """
    name = "stribeck"
    place = "link"
    linear = False
    parameters = {"static": (0.0, 0.0, _INF), "stribeck_velocity": (0.05, _TINY, _INF)}
    settings = {"smooth_velocity": (0.02, _TINY, _INF)}

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """τ_f [N·m] for joint velocities ``qd`` (``[n]`` or ``[N,n]``)."""
        v = self._values
        return v["static"] * np.exp(-(qd / v["stribeck_velocity"]) ** 2) * np.tanh(qd / v["smooth_velocity"])

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.friction(s.qd)


# ------------------------------------------------------------------------------------------------------------------
# torque-sensor effects that depend on the reversal travel
# ------------------------------------------------------------------------------------------------------------------
class Hysteresis(JointEffect):
    """Torque-sensor hysteresis vs. joint travel since the last reversal (thesis §2.1, Fig. 2.5).

    A Dahl law in the travel domain (the rate-independent solution of ``dτ/dr = σ(1 − τ/(d·τ_sat))``):
    ``τ_h = d·τ_sat + (τ_rev − d·τ_sat)·exp(−|r| / ρ)`` with ``d`` the segment's direction, ``r`` the reversal
    travel and ``τ_rev`` the value at the reversal (continuous across reversals; a fresh start is the virgin
    state τ_rev = 0). ``ρ = saturation_travel / 3`` so τ_h is within 5 % of saturation after ``saturation_travel``
    (6° → slope after 6° is e⁻³ ≈ 5 % of the slope at the reversal). Dahl was chosen over Bouc–Wen (more
    parameters, same loop shape for this purpose) and Preisach/Maxwell-slip (many elements) because two
    parameters per joint reproduce the thesis' loop and can be fitted from one triangular experiment.

    Parameters ``saturation`` τ_sat [N·m], ``load_gain`` [–] (τ_sat grows by ``load_gain·|τ|``, for the
    gravity-loaded joints 2/4), ``saturation_travel`` [rad] (YAML ``saturation_travel_deg``); setting
    ``reversal_velocity`` [rad/s] (deadband of the reversal detection).
    """
    name = "hysteresis"
    place = "sensor"
    linear = False
    parameters = {"saturation": (0.0, 0.0, _INF), "load_gain": (0.0, 0.0, _INF),
                  "saturation_travel": (math.radians(6.0), _TINY, _INF)}
    settings = {"reversal_velocity": (2e-3, 0.0, _INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        rt = travel or reversal_travel(s.q, s.qd, self.reversal_velocity)
        sat = self._load_scale(s, self.saturation, self.load_gain)
        rho = self.saturation_travel / 3.0
        out = np.empty_like(s.q)
        for j in range(self.n):
            st, anc, sd = rt.starts[j], rt.anchors[j], rt.seg_direction[j]
            ends = np.concatenate([st[1:] - 1, [s.q.shape[0] - 1]])
            # value carried into each segment: the law of segment k evaluated at the next anchor
            e = np.exp(-np.abs(anc[1:] - anc[:-1]) / rho[j])
            target = sd[:-1] * sat[ends[:-1], j]
            tau_rev = affine_scan(e, (1.0 - e) * target, 0.0)
            seg = rt.segment[:, j]
            d_sat = rt.direction[:, j] * sat[:, j]
            out[:, j] = d_sat + (tau_rev[seg] - d_sat) * np.exp(-np.abs(rt.r[:, j]) / rho[j])
        return out


class LostMotion(JointEffect):
    """Lost motion after a reversal: for ≈``window`` of travel the direction-dependent part of τ has not flipped.

    ``τ_lm = −d·c·A·exp(−(|r|/W)⁶)`` with ``d`` the new direction, ``r`` the reversal travel, ``A = amplitude +
    load_gain·|τ|`` the direction-dependent torque level that lags, ``c = 2`` after a reversal (the level flips from
    −dA to +dA) and ``c = 1`` when starting from standstill. With ``A`` equal to the Coulomb level the measured
    torque "barely changes" within the window (thesis §4 intro: absent changes of torque within ≈1° after
    reversals), then the full flip appears; the profile is flat (< 2 % change) up to W/2 and has released half
    of the flip at 0.94 W.

    Parameters ``amplitude`` A [N·m], ``load_gain`` [–], ``window`` W [rad] (YAML ``window_deg``); setting
    ``reversal_velocity`` [rad/s].
    """
    name = "lost_motion"
    place = "sensor"
    linear = False
    parameters = {"amplitude": (0.0, 0.0, _INF), "load_gain": (0.0, 0.0, _INF),
                  "window": (math.radians(1.0), _TINY, _INF)}
    settings = {"reversal_velocity": (2e-3, 0.0, _INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None,
               travel: ReversalTravel | None = None) -> np.ndarray:
        self._check_n(s)
        rt = travel or reversal_travel(s.q, s.qd, self.reversal_velocity)
        amp = self._load_scale(s, self.amplitude, self.load_gain)
        flip = np.where(rt.segment > 0, 2.0, 1.0)
        return -rt.direction * flip * amp * np.exp(-(np.abs(rt.r) / self.window) ** 6)


# ------------------------------------------------------------------------------------------------------------------
# other sensor effects
# ------------------------------------------------------------------------------------------------------------------
class Ripple(JointEffect):
    """Harmonic-drive torque ripple ``A sin(h·N·q + φ)`` [N·m]: its frequency ``h·N·|q̇|/2π`` follows joint speed.

    Fitted (linear) parameters ``sin_amplitude = A cos φ`` and ``cos_amplitude = A sin φ`` [N·m]; YAML may give
    ``amplitude`` + ``phase_deg`` instead. Settings ``gear_ratio`` N (100–160 on the iiwa) and ``harmonic`` h
    (cycles per wave-generator revolution, 2 for a harmonic drive).
    """
    name = "ripple"
    place = "sensor"
    linear = True
    parameters = {"sin_amplitude": (0.0, -_INF, _INF), "cos_amplitude": (0.0, -_INF, _INF)}
    settings = {"gear_ratio": (160.0, _TINY, _INF), "harmonic": (2.0, _TINY, _INF)}

    @classmethod
    def from_config(cls, block: dict | None, n: int) -> "JointEffect":
        block = dict(block or {})
        if "amplitude" in block:
            amp = np.asarray(block.pop("amplitude"), dtype=float)
            phase = np.radians(np.asarray(block.pop("phase_deg", 0.0), dtype=float))
            if np.any(amp < 0):
                raise EffectConfigError(f"ripple.amplitude must be >= 0, got {amp}")
            block["sin_amplitude"], block["cos_amplitude"] = amp * np.cos(phase), amp * np.sin(phase)
        return super().from_config(block, n)

    def _phase(self, s: MotionSignals) -> np.ndarray:
        return self.harmonic * self.gear_ratio * s.q

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        ph = self._phase(s)
        return self.sin_amplitude * np.sin(ph) + self.cos_amplitude * np.cos(ph)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        ph = self._phase(s)
        return _diagonal_regressor([np.sin(ph), np.cos(ph)])


class SensorOffsetGain(JointEffect):
    """Torque-sensor offset and gain error: contribution ``g·τ + o`` (measured = (1+g)·τ + o).

    Parameters ``offset`` o [N·m] and ``gain`` g [–] (relative); needs ``MotionSignals.tau``.
    """
    name = "sensor_offset_gain"
    place = "sensor"
    linear = True
    parameters = {"gain": (0.0, -0.5, 0.5), "offset": (0.0, -_INF, _INF)}

    def _tau(self, s: MotionSignals) -> np.ndarray:
        if s.tau is None:
            raise ValueError("sensor_offset_gain: MotionSignals.tau (the torque entering the sensor) is required")
        return s.tau

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.gain * self._tau(s) + self.offset

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return _diagonal_regressor([self._tau(s), np.ones_like(s.q)])


class TorqueNoise(JointEffect):
    """White Gaussian torque-sensor noise, standard deviation ``std`` [N·m] per joint (needs a seeded ``rng``)."""
    name = "torque_noise"
    place = "sensor"
    linear = False
    parameters = {"std": (0.0, 0.0, _INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        if rng is None:
            raise ValueError("torque_noise: a seeded rng (np.random.Generator) is required")
        return rng.standard_normal(s.q.shape) * self.std


class EncoderNoise(JointEffect):
    """Joint position sensor: white noise ``std`` [rad] then quantisation to ``resolution`` [rad] (0 = none).

    It contributes no torque; :meth:`measure` turns true positions into measured ones (YAML ``std_deg``,
    ``resolution_deg``).
    """
    name = "encoder_noise"
    place = "sensor"
    linear = False
    parameters = {"std": (0.0, 0.0, _INF)}
    settings = {"resolution": (0.0, 0.0, _INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return np.zeros_like(s.q)

    def measure(self, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured positions ``[N,n]`` rad for true ``q``."""
        q_meas = q + rng.standard_normal(q.shape) * self.std
        res = self.resolution
        return np.where(res > 0, np.round(q_meas / np.where(res > 0, res, 1.0)) * res, q_meas)


class Motor(JointEffect):
    """The motor side of the drive, hidden behind the torque sensor: reflected motor inertia B and motor friction.
    Configured by the twin's top-level ``drive`` block; not in :data:`EFFECTS`, because it adds nothing to τ_J that
    a fit on torque data could find.

    Motor side ``B θ̈ = τ_m − τ_f,m(θ̇) − τ_J``. With a rigid drive (θ = q) Drake's plant carries B as reflected rotor
    inertia and the sensor sees ``τ_J = τ_m − τ_f,m − B q̈``; with ``elasticity`` the drive integrates θ. Either way
    τ_J = τ_rbd + τ_f,link − Jᵀ f_ext is fixed by the link motion, so :meth:`torque` is zero: these effects show up only
    through the motion (tracking error, inertia the controller must move).

    Parameters ``motor_inertia`` B [kg·m²] (link-side reflected, ``ρ² I_rotor``), ``motor_viscous`` [N·m·s/rad],
    ``motor_coulomb`` [N·m]; setting ``smooth_velocity`` [rad/s].
    """
    name = "motor"
    place = "motor"
    linear = False
    parameters = {"motor_inertia": (0.0, 0.0, _INF), "motor_viscous": (0.0, 0.0, _INF),
                  "motor_coulomb": (0.0, 0.0, _INF)}
    settings = {"smooth_velocity": (0.02, _TINY, _INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return np.zeros_like(s.q)

    def friction(self, theta_dot: np.ndarray) -> np.ndarray:
        """Motor-side friction [N·m] (hidden from τ_J), dissipative."""
        v = self._values
        return v["motor_viscous"] * theta_dot + v["motor_coulomb"] * np.tanh(theta_dot / v["smooth_velocity"])


class Elasticity(JointEffect):
    """Series-elastic joint with a motor-side state (thesis eq. 3.6), simulated by ``proprio.systems.joint_drive``
    with the twin's ``drive`` block (:class:`Motor`: motor inertia B and motor friction); the spring is Drake's
    implicit PD-controlled actuator, so realistic stiffness is stable at 1 ms.

    Spring ``τ_s = K(θ − q) + D(θ̇ − q̇)`` between motor angle θ and link angle q drives the link and is what the
    sensor measures. The torque sensor sits on the link side, so τ_J is fully determined by the link motion
    (``τ_rbd + τ_f,link − Jᵀf_ext``): elasticity adds **nothing directly** to τ_J (:meth:`torque` is zero). It shows up
    in the data through the motion: a deflection ``τ/K`` of the link from the motor-side-controlled position, a
    tracking lag and a lightly damped resonance near ``√(K/μ)`` in q and hence in τ_rbd(q, q̇, q̈); and a motor-side
    position sensor would read θ ≠ q (the twin, like the iiwa, measures the link-side q).

    Parameters ``stiffness`` K [N·m/rad] (> 0), ``damping`` D [N·m·s/rad].
    """
    name = "elasticity"
    place = "motor"
    linear = False
    parameters = {"stiffness": (1e4, _TINY, _INF), "damping": (10.0, 0.0, _INF)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return np.zeros_like(s.q)


# ------------------------------------------------------------------------------------------------------------------
# registry
# ------------------------------------------------------------------------------------------------------------------
EFFECTS: dict[str, type[JointEffect]] = {cls.name: cls for cls in (
    ViscousCoulomb, Stribeck, Hysteresis, LostMotion, Ripple, SensorOffsetGain, TorqueNoise, EncoderNoise, Elasticity)}


def make_effects(config: dict | None, n: int) -> list[JointEffect]:
    """Build the effects of a YAML ``effects:`` mapping ``{name: block}`` in registry order (link, sensor, motor).

    Unknown names raise :class:`EffectConfigError` listing the valid ones (the payload and the motor side have the
    twin's own ``payload`` and ``drive`` blocks).
    """
    config = config or {}
    if not isinstance(config, dict):
        raise EffectConfigError(f"effects must be a mapping {{name: parameters}}, got {config!r}")
    unknown = sorted(set(config) - set(EFFECTS))
    if unknown:
        hint = " (the payload has its own top-level 'payload' block)" if "payload" in unknown else ""
        raise EffectConfigError(f"unknown joint effect(s) {unknown}{hint}; valid effects: {sorted(EFFECTS)}")
    return [cls.from_config(config[name], n) for name, cls in EFFECTS.items() if name in config]
