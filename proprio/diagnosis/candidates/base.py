"""Candidate explanations of the torque gap (see :mod:`proprio.diagnosis.selection.forward`): the :class:`Candidate`
interface, every library effect the model lacks (:class:`EffectCandidate`, :func:`ripple_candidate`), the data path's
signal lag and encoder noise, and elasticity. The rigid-body and payload candidates:
:mod:`proprio.diagnosis.candidates.rigid_body`; a drive torque's: :mod:`proprio.diagnosis.candidates.drive`; the set
a diagnosis tests: :func:`proprio.diagnosis.candidates.registry.candidate_set`."""
from __future__ import annotations

import inspect
import math
from typing import Any, Hashable, Sequence

import numpy as np
from scipy import signal

from proprio.conditioning import zero_phase_lowpass
from proprio.diagnosis.data import DiagnosisError, GapData, SimModel
from proprio.diagnosis.localisation import peak_orders
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS, JointEffect, effect_key, register_plugin, resolve_effect
from proprio.reversals import ReversalTravel, reversal_travel
from proprio.signals import MotionSignals

__all__ = ["Candidate", "EffectCandidate", "SignalLagCandidate", "EncoderNoiseCandidate", "ElasticityCandidate",
           "ripple_candidate"]


class Candidate:
    """Something that may explain part of the residual. Linear ones provide ``design(data) -> [M, n, p]`` (at the
    data's kept samples); nonlinear ones ``torque(theta, data) -> [M, n]``, ``starts``, ``bounds``. A physical
    candidate turns its fitted ``theta`` into a twin-config fragment with :meth:`patch`."""
    name: str = ""
    linear: bool = True
    place: str = ""
    processing: bool = False          # describes the data path, not the robot (reported apart, never as the cause)
    time_varying: bool = False        # depends on the session clock (fitted without the time-trend nuisance)
    patch_note: str = ""              # what :meth:`patch` did beyond copying parameters (a comment of the patch)

    def patch(self, theta: np.ndarray) -> dict[str, Any] | None:
        """The fitted candidate as a twin-config fragment (``effects:`` / ``payload:`` / ``robot:`` blocks, SI
        units), or ``None`` where the twin cannot express it (data-path steps never go into a patch)."""
        return None

    def param_names(self) -> list[str]:
        raise NotImplementedError

    @property
    def n_params(self) -> int:
        return len(self.param_names())

    def design(self, data: GapData) -> np.ndarray:
        raise NotImplementedError

    def torque(self, theta: np.ndarray, data: GapData) -> np.ndarray:
        raise NotImplementedError

    def starts(self, data: GapData) -> list[np.ndarray]:
        raise NotImplementedError

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return -np.inf * np.ones(self.n_params), np.inf * np.ones(self.n_params)

    def prior_precision(self) -> np.ndarray:
        """``1/σ²`` of a zero-mean Gaussian prior per parameter for the linear fit (0: none; see
        :attr:`proprio.effects.base.JointEffect.prior_std`)."""
        return np.zeros(self.n_params)

    def joint_of_param(self, n: int) -> np.ndarray:
        """Joint each parameter acts on (-1: several joints) — used for the sparse finite-difference Jacobian."""
        return -np.ones(self.n_params, dtype=int)

    @property
    def design_key(self) -> Hashable:
        """What the cached design of :meth:`cached_design` is filed under in ``data.cache`` (the name; a candidate
        whose columns depend on its settings adds them)."""
        return self.name

    def cached_design(self, data: GapData) -> np.ndarray:
        key = ("design", self.design_key)
        if key not in data.cache:
            data.cache[key] = self.design(data)
        return data.cache[key]


def _kept_signals(data: GapData) -> list[MotionSignals]:
    """The data's motion signals at their kept samples (``fit_index``), per recording; cached in ``data``."""
    key = ("kept_signals",)
    if key not in data.cache:
        data.cache[key] = [MotionSignals(s.t[i], s.q[i], s.qd[i], s.qdd[i], None if s.tau is None else s.tau[i])
                           for s, i in zip(data.signals, data.fit_index)]
    return data.cache[key]


class EffectCandidate(Candidate):
    """A joint effect: a library name, a plugin path ``"package.module:Class"`` or a ``JointEffect`` subclass
    (:mod:`proprio.effects.plugins`); the candidate is named by the class' ``name``. Linear effects are fitted through
    their own ``regressor``; nonlinear ones start from the class defaults with every torque-amplitude parameter
    (default 0) set to a fraction of the residual's RMS per joint (two starts)."""
    AMPLITUDE_KEYS = ("static", "saturation", "amplitude", "offset", "level")

    def __init__(self, effect: str | type[JointEffect], n: int, keys: Sequence[str] | None = None,
                 label: str | None = None, **settings: Any):
        cls = resolve_effect(effect) if isinstance(effect, str) else effect
        if not (isinstance(cls, type) and issubclass(cls, JointEffect)):
            raise DiagnosisError(f"candidate {effect!r} is neither an effect name nor a JointEffect subclass")
        if EFFECTS.get(cls.name) is not cls:
            register_plugin(cls)        # a class handed over by Python code: its path resolves from now on
        self.name = label or cls.name
        self.effect = effect_key(cls)
        self.proto: JointEffect = cls(n, **settings)
        self.linear = bool(self.proto.linear)
        self.place = self.proto.place
        self.time_varying = bool(self.proto.time_varying)
        # a library effect's torque at a sample depends on that sample alone (evaluated at the kept samples only),
        # except for the reversal-travel ones, whose state is the travel since the last reversal (:meth:`_travel_view`)
        library = EFFECTS.get(cls.name) is cls
        self._takes_travel = (library and "travel" in inspect.signature(cls.torque).parameters
                              and "reversal_velocity" in type(self.proto).settings)
        self._pointwise = library and "travel" not in inspect.signature(cls.torque).parameters
        all_keys = list(type(self.proto).parameters)
        self._keys = list(keys) if keys else all_keys
        self._cols = np.concatenate([np.arange(n) + n * all_keys.index(k) for k in self._keys])
        self._n = n

    def param_names(self) -> list[str]:
        return [f"{k}[{j + 1}]" for k in self._keys for j in range(self._n)]

    def design(self, data: GapData) -> np.ndarray:
        if self._pointwise:
            return np.concatenate([self.proto.regressor(s)[..., self._cols] for s in _kept_signals(data)])
        return data.stack([self.proto.regressor(s)[..., self._cols] for s in data.signals])

    def torque(self, theta: np.ndarray, data: GapData) -> np.ndarray:
        eff = self.proto.with_vector(np.asarray(theta, dtype=float))
        if self._pointwise:
            return np.concatenate([eff.torque(s) for s in _kept_signals(data)])
        if not self._takes_travel:
            return data.stack([eff.torque(s) for s in data.signals])
        out = []
        for k in range(len(data.signals)):
            s_u, travel, at = self._travel_view(data, k, eff)
            out.append(eff.torque(s_u, travel=travel)[at])
        return np.concatenate(out)

    def _travel_view(self, data: GapData, k: int, eff: JointEffect
                     ) -> tuple[MotionSignals, ReversalTravel, np.ndarray]:
        """Recording ``k`` for a reversal-travel effect: ``(signals, travel, positions of the kept samples in
        them)``. The travel (at the effect's ``reversal_velocity`` setting, never a fitted parameter) is computed
        once on the whole recording; its state enters the law only per segment between reversals (the value at each
        segment's first and last sample) and per sample, so the signals and travel are cut to the kept samples plus
        every segment's first and last one — the law's values there are those of the whole recording, at a fraction
        of the cost on a long, strided training set. Cached in ``data``."""
        rv = np.asarray(eff.reversal_velocity, dtype=float)
        key = ("travel", k, rv.tobytes())
        if key not in data.cache:
            s, kept = data.signals[k], data.fit_index[k]
            rt = reversal_travel(s.q, s.qd, rv)
            u = np.unique(np.concatenate([kept, *rt.starts, *(st[1:] - 1 for st in rt.starts)]))
            if 2 * u.size > s.q.shape[0]:                      # little to cut: the whole recording
                data.cache[key] = (s, rt, kept)
            else:
                at = lambda i: np.searchsorted(u, i)  # noqa: E731
                cut = ReversalTravel(rt.r[u], rt.direction[u], rt.segment[u], tuple(at(st) for st in rt.starts),
                                     rt.anchors, rt.seg_direction)
                s_u = MotionSignals(s.t[u], s.q[u], s.qd[u], s.qdd[u], None if s.tau is None else s.tau[u])
                data.cache[key] = (s_u, cut, at(kept))
        return data.cache[key]

    def starts(self, data: GapData) -> list[np.ndarray]:
        """Library defaults with zero amplitudes set to 1 and 0.3 × the residual RMS; a time constant [s] starts at
        its default, then at a quarter of the session span the data cover (a fast and a slow change)."""
        v = np.asarray(self.proto.vector(), dtype=float).reshape(len(self._keys), self._n)
        scale = np.sqrt((data.residual ** 2).mean(axis=0))
        span = max((float(t[-1]) + s0 for t, s0 in zip(data.times, data.session_s)), default=0.0)
        out = []
        for f in (1.0, 0.3):
            x = v.copy()
            for i, k in enumerate(self._keys):
                if k in self.AMPLITUDE_KEYS and not np.any(x[i]):
                    x[i] = f * scale
                if k == "time_constant" and f < 1.0 and span > 0:
                    lo, hi = type(self.proto).parameters[k][1:]
                    x[i] = np.clip(0.25 * span, lo, hi)
            out.append(x.reshape(-1))
        return out

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.proto.bounds()
        return np.asarray(lo, dtype=float)[self._cols], np.asarray(hi, dtype=float)[self._cols]

    def prior_precision(self) -> np.ndarray:
        return self.proto.prior_precision()[self._cols]

    def joint_of_param(self, n: int) -> np.ndarray:
        return np.tile(np.arange(n), len(self._keys))

    def patch(self, theta: np.ndarray) -> dict[str, Any] | None:
        """``{"effects": {effect: {fitted keys + settings}}}`` (a partial fit, e.g. ``sensor_offset``, gives only
        its own keys, so offset and gain merge into one ``sensor_offset_gain`` block)."""
        theta = np.asarray(theta, dtype=float).reshape(len(self._keys), self._n)
        lo, hi = (b.reshape(len(self._keys), self._n) for b in self.bounds())
        out = (theta < lo) | (theta > hi)
        self.patch_note = ""
        if out.any():     # the diagnosis fits within the bounds; a θ from elsewhere may not be, the twin refuses it
            bad = [f"{self._keys[i]}[{j + 1}] = {theta[i, j]:.3g}" for i, j in zip(*np.nonzero(out))]
            self.patch_note = (f"{self.name}: outside the effect's bounds, clipped to them in the patch: "
                               f"{', '.join(bad)}")
            theta = np.clip(theta, lo, hi)
        block = {k: theta[i].tolist() for i, k in enumerate(self._keys)}
        block.update({k: v.tolist() for k, v in self.proto.params().items() if k in type(self.proto).settings})
        return {"effects": {self.effect: block}}


def ripple_candidate(n: int, train: "GapData", max_order: float = 400.0, min_order: float = 60.0) -> EffectCandidate:
    """The library's ripple ``A sin(h·N·q + φ)`` with its order ``h·N`` per joint set to the peak of the training
    residual's order spectrum between ``min_order`` and ``max_order`` cycles per revolution (the ripple is linear once
    its order is known; the order is found, not assumed). Harmonic drives have ratios N ≥ 30 and h = 2, so orders below
    60 are not ripple: there a rigid-body error of the joint's own link (a few cycles per revolution) would win."""
    q = train.stack([s.q for s in train.signals])
    qd = train.stack([s.qd for s in train.signals])
    orders = peak_orders(train.residual, q, qd, max_order=max_order, min_order=min_order)
    harmonic = 2.0
    return EffectCandidate("ripple", n, gear_ratio=orders / harmonic, harmonic=harmonic)


class EncoderNoiseCandidate(Candidate):
    """Position-sensor noise: the residual is the model's error from noisy q (and q̇, q̈ derived from it). Its
    signature is ``d_j = τ_sim(smoothed motion)_j − τ_sim(raw motion)_j`` (zero-phase low-pass at ``cutoff_hz``,
    well above arm motion and below encoder noise); the fitted share ``c_j`` should be ≈ 1 where it is real."""
    name = "encoder_noise"
    place = "sensor"
    processing = True

    def __init__(self, model: "SimModel", cutoff_hz: float = 8.0):
        self.model, self.cutoff_hz = model, cutoff_hz

    def param_names(self) -> list[str]:
        return [f"share[{j + 1}]" for j in range(self.model.robot.n)]

    def design(self, data: GapData) -> np.ndarray:
        out = []
        for s, sim in zip(data.signals, data.tau_sim):
            rate = 1.0 / float(np.median(np.diff(s.t)))
            if rate <= 2.5 * self.cutoff_hz:
                out.append(np.zeros(s.q.shape + (s.n,)))
                continue
            sos = signal.butter(2, self.cutoff_hz, fs=rate, output="sos")
            smooth = [signal.sosfiltfilt(sos, x, axis=0) for x in (s.q, s.qd, s.qdd)]
            d = self.model.predict(MotionSignals(s.t, *smooth, tau=s.tau)) - sim
            out.append(d[:, :, None] * np.eye(s.n)[None])
        return data.stack(out)

    def joint_of_param(self, n: int) -> np.ndarray:
        return np.arange(n)


class ElasticityCandidate(Candidate):
    """Joint elasticity seen by a motor-side position sensor: the measured q includes the spring deflection
    ``δ = c∘τ_J`` (compliance ``c_k = 1/K_k`` [rad/(N·m)]), so the model evaluates the rigid body at the wrong
    motion: ``e ≈ −Σ_k (∂τ/∂q_k τ_k + ∂τ/∂q̇_k τ̇_k + ∂τ/∂q̈_k τ̈_k) c_k`` (linear in ``c``; τ the modelled
    link torque, its derivatives by finite differences of its low-pass with the motion's conditioning cutoffs). With a
    link-side position sensor elasticity leaves τ_J = τ_rbd(q, q̇, q̈) exact and cannot show in this residual
    (``proprio.effects.Elasticity``)."""
    name = "elasticity"
    place = "motor"

    def __init__(self, model: "SimModel", accel: float = 1.0):
        self.model, self.accel = model, accel

    def param_names(self) -> list[str]:
        return [f"compliance[{j + 1}]" for j in range(self.model.robot.n)]

    def design(self, data: GapData) -> np.ndarray:
        out = []
        for s, cs, i in zip(data.signals, data.conditioned, data.fit_index):
            n, tau = s.n, s.tau
            # the deflection reaches q̇, q̈ through the same low-pass as the measured motion
            smooth = zero_phase_lowpass(tau, cs.rate_hz, cs.cutoff_hz)
            tau_d = np.gradient(smooth, s.t, axis=0)
            tau_dd = np.gradient(tau_d, s.t, axis=0)
            q, qd, qdd = s.q[i], s.qd[i], s.qdd[i]                  # the rigid body at the kept samples only
            cols = np.empty(q.shape + (n,))
            for k in range(n):
                # directional derivative of τ_rbd along the deflection (τ_k, τ̇_k, τ̈_k)·c_k of joint k
                h = 1e-3 / max(float(np.abs(tau[:, k]).max()), 1e-9)
                dirs = [np.zeros_like(q) for _ in range(3)]
                dirs[0][:, k], dirs[1][:, k], dirs[2][:, k] = h * tau[i, k], h * tau_d[i, k], h * tau_dd[i, k]
                plus = inverse_dynamics(self.model.robot, q + dirs[0], qd + dirs[1], qdd + self.accel * dirs[2])
                minus = inverse_dynamics(self.model.robot, q - dirs[0], qd - dirs[1], qdd - self.accel * dirs[2])
                cols[:, :, k] = -(plus - minus) / (2 * h)
            out.append(cols)
        return np.concatenate(out)

    def joint_of_param(self, n: int) -> np.ndarray:
        return -np.ones(n, dtype=int)


class SignalLagCandidate(Candidate):
    """A first-order lag of time constant ``T_j`` [s] between the modelled and the measured torque (a causal
    filter in the torque channel): ``e ≈ LP_T(τ_sim) − τ_sim`` with ``LP_T`` the exactly discretised first-order
    low-pass. Nonlinear in ``T``, one parameter per joint."""
    name = "signal_lag"
    place = "sensor"
    linear = False
    processing = True

    def __init__(self, n: int):
        self.n = n

    def param_names(self) -> list[str]:
        return [f"time_constant[{j + 1}]" for j in range(self.n)]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(self.n), np.full(self.n, 0.2)

    def starts(self, data: GapData) -> list[np.ndarray]:
        return [np.full(self.n, 0.005), np.full(self.n, 0.03)]

    def torque(self, theta: np.ndarray, data: GapData) -> np.ndarray:
        out = []
        for s, sim in zip(data.signals, data.tau_sim):
            dt = float(np.median(np.diff(s.t)))
            y = np.empty_like(sim)
            for j in range(self.n):
                a = math.exp(-dt / theta[j]) if theta[j] > 1e-9 else 0.0
                y[:, j] = signal.lfilter([1 - a], [1, -a], sim[:, j] - sim[0, j]) + sim[0, j]
            out.append(y - sim)
        return data.stack(out)

    def joint_of_param(self, n: int) -> np.ndarray:
        return np.arange(n)
