"""Candidate explanations of the torque gap: every library effect the model lacks, plus rigid-body parameter error,
an unmodelled payload, signal lag, encoder noise and elasticity (see :mod:`proprio.diagnosis.selection`)."""
from __future__ import annotations

import inspect
import math
from dataclasses import replace
from typing import Any, Callable, Sequence

import numpy as np
from scipy import linalg, signal

from proprio.conditioning import zero_phase_lowpass
from proprio.description import RobotDescription
from proprio.diagnosis.data import DiagnosisError, GapData, SimModel
from proprio.diagnosis.localisation import peak_orders
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS, JointEffect, effect_key, register_plugin, resolve_effect
from proprio.identification.regressor import (PARAMS_PER_JOINT, drive_columns, drive_identified, n_parameters,
                                              parameter_names, regressor)
from proprio.reversals import ReversalTravel, reversal_travel
from proprio.signals import MotionSignals

__all__ = ["Candidate", "EffectCandidate", "RigidBodyCandidate", "PayloadCandidate", "SignalLagCandidate",
           "EncoderNoiseCandidate", "ElasticityCandidate", "ripple_candidate", "candidate_set", "DriveCandidate",
           "DRIVE_CANDIDATES", "GAUGE_ONLY", "DRIVE_ONLY", "tau_kind"]


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

    def joint_of_param(self, n: int) -> np.ndarray:
        """Joint each parameter acts on (-1: several joints) — used for the sparse finite-difference Jacobian."""
        return -np.ones(self.n_params, dtype=int)

    def cached_design(self, data: GapData) -> np.ndarray:
        key = ("design", self.name)
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
    residual's order spectrum between ``min_order`` and ``max_order`` cycles per revolution (the ripple is linear once its
    order is known; the order is found, not assumed). Harmonic drives have ratios N ≥ 30 and h = 2, so orders below
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
    link torque, its derivatives by finite differences of its low-pass with the motion's conditioning cutoffs). With a link-side position sensor elasticity leaves
    τ_J = τ_rbd(q, q̇, q̈) exact and cannot show in this residual (``proprio.effects.Elasticity``)."""
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
        train.cache[("design", self.name)] = full[..., self.columns]
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


DRIVE_CANDIDATES = ("rotor_inertia", "motor_friction", "drive_offset")
"""The drive's terms the model may lack, as candidates (:class:`DriveCandidate`)."""

GAUGE_ONLY = ("hysteresis", "lost_motion", "ripple", "sensor_offset")
"""Candidates of a joint-torque sensor's strain gauge (its loop, its lost motion, its ripple, its zero): not
candidates when τ is a drive torque (current × torque constant × gear ratio has no gauge; a drive's constant bias is
``drive_offset``). A gain error stays a candidate for both kinds (a drive torque's is a torque-constant error)."""

DRIVE_ONLY = DRIVE_CANDIDATES + ("presliding",)
"""Candidates only a drive torque sees: rotor inertia, the motor's friction and the drive's offsets sit before a
link-side torque sensor, and pre-sliding friction is, in τ, the Dahl law of the gauge's hysteresis (one law, the
same function of the reversal travel: :mod:`proprio.effects.dahl`), which a link sensor's diagnosis names
hysteresis."""


def tau_kind(robot: RobotDescription) -> str:
    """What the model's τ channel is: ``drive`` when the description's drive block says ``tau_kind: drive`` (its
    drive terms are in the model), else ``link_sensor`` (:mod:`proprio.drive_description`)."""
    return "drive" if drive_identified(robot) else "link_sensor"


class DriveCandidate(Candidate):
    """A drive term a drive-torque arm's model lacks (``robot.drive.tau_kind == 'drive'``), linear in its
    parameters, on the law of :func:`proprio.identification.regressor.drive_columns` (the identification's, with the
    description's coupling ``C``): ``rotor_inertia`` ``Cᵀ(I_a ⊙ C q̈)`` (I_a [kg·m²] per motor), ``motor_friction``
    ``Cᵀ(F_v,m ⊙ C q̇ + F_c,m ⊙ sgn_s(C q̇))`` ([N·m·s/rad], [N·m] per motor: a motor shared by coupled joints brakes
    each of them through Cᵀ) and ``drive_offset`` τ_0 [N·m] per joint. The fit is the part the model lacks: the
    patch adds it to the description's drive block. ``motors`` (0-based) restricts the motor terms to those motors
    (default all): an uncoupled motor's friction is the joint's own (:func:`candidate_set`)."""
    place = "motor"

    def __init__(self, robot: RobotDescription, group: str, motors: Sequence[int] | None = None):
        if group not in DRIVE_CANDIDATES:
            raise DiagnosisError(f"drive candidate {group!r}: must be one of {DRIVE_CANDIDATES}")
        if not drive_identified(robot):
            raise DiagnosisError(f"drive candidate {group}: the robot description {robot.name!r} has no drive block "
                                 "with tau_kind: drive")
        self.robot, self.name, n = robot, group, robot.n
        self._motors = np.arange(n) if motors is None else np.asarray(motors, dtype=int)
        groups = {"rotor_inertia": (0,), "motor_friction": (1, 2)}.get(group)
        self._cols = None if groups is None else np.concatenate([g * n + self._motors for g in groups])

    def param_names(self) -> list[str]:
        keys = {"rotor_inertia": ("I_a",), "motor_friction": ("F_v,m", "F_c,m"), "drive_offset": ("offset",)}
        index = range(self.robot.n) if self._cols is None else self._motors
        return [f"{k}[{j + 1}]" for k in keys[self.name] for j in index]

    def design(self, data: GapData) -> np.ndarray:
        if self._cols is None:
            return data.stack([np.broadcast_to(np.eye(s.n), s.q.shape + (s.n,)) for s in data.signals])
        drive = self.robot.drive
        return data.stack([np.moveaxis(drive_columns(drive, s.qd.T, s.qdd.T, None), -1, 0)[..., self._cols]
                           for s in data.signals])

    def joint_of_param(self, n: int) -> np.ndarray:
        if self._cols is None:
            return np.arange(n)
        if not self.robot.drive.coupled:
            return np.tile(self._motors, self.n_params // len(self._motors))
        return -np.ones(self.n_params, dtype=int)

    def patch(self, theta: np.ndarray) -> dict[str, Any] | None:
        """``{"robot": <description mapping>}`` with the fit added to its drive block's parameters."""
        drive = self.robot.drive
        theta = np.asarray(theta, dtype=float)
        p, offset = drive.parameters(), np.asarray(drive.offset, dtype=float)
        if self._cols is None:
            offset = offset + theta
        else:
            p[self._cols] += theta
        lo = np.zeros_like(p)
        self.patch_note = ""
        if np.any(p < lo):
            self.patch_note = (f"{self.name}: a fitted drive parameter below zero (rotor inertia and motor friction "
                               f"are not negative), clipped to 0 in the patch")
            p = np.maximum(p, lo)
        desc = replace(self.robot, drive=drive.with_parameters(p, offset)).to_dict()
        desc["name"] = self.robot.name
        return {"robot": desc}


def candidate_set(model: SimModel, train: GapData, names: Sequence[str] | None = None,
                  plugins: Sequence[str | type[JointEffect]] = (), time_varying: bool = False) -> list[Candidate]:
    """All deterministic candidates the model lacks (or only ``names``, which must be among them), plus the user's
    ``plugins`` (plugin paths ``"package.module:Class"`` or ``JointEffect`` subclasses, tested alongside; a plugin
    path in ``names`` counts as one). What τ is decides the rest (:func:`tau_kind`): for drive torques the drive's
    terms (:data:`DRIVE_CANDIDATES`; an uncoupled motor's friction only when the model has link friction, else it is
    the ``viscous_coulomb`` candidate) and pre-sliding friction, never the gauge's effects (:data:`GAUGE_ONLY`); for a
    link-side torque sensor never those of :data:`DRIVE_ONLY`. The time-varying library effects are offered only when ``time_varying`` (the
    residual depends on the session time, :mod:`proprio.diagnosis.time_variation`) or when named. Raises
    :class:`DiagnosisError` for a plugin that cannot be resolved or that the model already has."""
    n = model.robot.n
    present = model.effect_names
    plugins = list(plugins) + [k for k in names or () if ":" in k]
    names = None if names is None else [k for k in names if ":" not in k]
    extra: dict[str, EffectCandidate] = {}
    for p in plugins:
        try:
            cand = EffectCandidate(p, n)
        except ValueError as exc:
            raise DiagnosisError(f"candidates: {exc}") from exc
        if cand.name in present or cand.name in extra:
            raise DiagnosisError(f"candidates: plugin {cand.effect} ({cand.name}) is already in the model or "
                                 "given twice")
        extra[cand.name] = cand
    special = {"ripple": lambda: ripple_candidate(n, train), "encoder_noise": lambda: EncoderNoiseCandidate(model),
               "elasticity": lambda: ElasticityCandidate(model)}
    available: dict[str, Callable[[], Candidate]] = {
        k: special.get(k, lambda k=k: EffectCandidate(k, n)) for k in EFFECTS
        if k not in present and k not in ("torque_noise", "sensor_offset_gain")}
    if "sensor_offset_gain" not in present:
        # offset and gain error are tested apart: a gain error aliases a scaled rigid body, an offset does not
        available["sensor_offset"] = lambda: EffectCandidate("sensor_offset_gain", n, ("offset",), "sensor_offset")
        available["sensor_gain"] = lambda: EffectCandidate("sensor_offset_gain", n, ("gain",), "sensor_gain")
    names = None if names is None else [x for k in names for x in
                                        (("sensor_offset", "sensor_gain") if k == "sensor_offset_gain" else (k,))]
    kind = tau_kind(model.robot)
    if kind == "drive":
        available.update({k: (lambda k=k: DriveCandidate(model.robot, k)) for k in DRIVE_CANDIDATES})
        if "viscous_coulomb" in available:          # an uncoupled motor's friction is the viscous_coulomb candidate:
            c = model.robot.drive.normalized_coupling            # the motor friction candidate keeps the motors
            shared = np.flatnonzero(np.count_nonzero(c, axis=1) > 1)   # that turn with several joints, if any
            if shared.size:
                available["motor_friction"] = lambda: DriveCandidate(model.robot, "motor_friction", shared)
            else:
                del available["motor_friction"]
    unseen = GAUGE_ONLY if kind == "drive" else DRIVE_ONLY
    for k in unseen:
        available.pop(k, None)
    available["rigid_body"] = lambda: RigidBodyCandidate.of(model.robot, train)
    available["payload"] = lambda: PayloadCandidate(model.robot)
    available["signal_lag"] = lambda: SignalLagCandidate(n)
    if names is not None:
        unknown = [k for k in names if k not in available and k != "torque_noise"]
        if unknown:
            why = [f"{k} (already in the model)" if k in present else f"{k} (a {kind} τ cannot show it)"
                   if k in unseen else f"{k} (unknown)" for k in unknown]
            raise DiagnosisError(f"candidates: cannot test {', '.join(why)}; available: {sorted(available)} or a "
                                 "plugin 'package.module:Class'")
        chosen = [k for k in names if k in available]
    else:
        chosen = [k for k in available if time_varying or k not in EFFECTS or not EFFECTS[k].time_varying]
    if not chosen and not extra:
        raise DiagnosisError("candidates: no candidate effects left to test — the model already has every effect "
                             "of the library (or only noise effects were requested)")
    return [available[k]() for k in chosen] + list(extra.values())
