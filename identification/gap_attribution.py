"""Which unmodelled effect causes the sim-to-real torque gap, and how far does it shrink? (DESIGN.md "Gap
diagnosis", steps 3–4.)

Candidates are every deterministic effect of the twin's joint-effect library (``proprio.systems.joint_effects``)
that the simulation model lacks, plus

* ``rigid_body``: an error of the rigid-body parameters — a correction ``δβ`` of the identifiable (base) inertial
  parameters, ``e ≈ Y_b(q, q̇, q̈) δβ`` with ``Y_b`` the columns of the Newton–Euler regressor
  (``identification/regressor.py``) kept by a rank-revealing QR of the training regressor;
* ``payload``: an unmodelled point mass at the flange, linear in ``(m, m·c)`` with ``c`` in the flange frame (the
  payload's own rotational inertia is neglected), i.e. ``Jᵀ`` of the point's weight and inertial force;
* ``signal_lag``: a time shift ``δ_j`` between measured and simulated torque, ``e ≈ −δ_j dτ_sim/dt`` — the usual
  alias of elasticity and of a causal filter in the torque channel (a confusable pair DESIGN.md names).

Each candidate is fitted to the residual ``e = τ_meas − τ_sim`` of the TRAINING recordings — by weighted linear
least squares where it is linear in its parameters (the effect's own ``regressor``), by bounded
``scipy.optimize.least_squares`` otherwise — and scored by the reduction of the weighted squared residual on the
HELD-OUT recordings. Greedy forward selection adds the best candidate, refits all selected ones jointly
(linear ones exactly, nonlinear ones by back-fitting) and repeats while the gain is significant.

**Selection test.** The held-out samples are cut into ``B`` contiguous time blocks of ≈ 0.5 s (at least 20;
longer than the residual's correlation time, so block statistics are close to independent even when ``e`` is
strongly autocorrelated — the reason for blocks rather than samples). With ``w_j = 1/mean(e_train,j²)`` (every
joint counts, whatever its torque scale) and ``SSE_b = Σ_{t∈b,j} w_j r²``, the per-block statistic is the
log-ratio ``l_b = log(SSE_b(S) / SSE_b(S+c))`` — scale-free, so a lag or friction that matters in every block is
not drowned by the few blocks of fast reaches. A candidate is *significant* when (i) its relative gain
``G = 1 − Σ SSE_b(S+c) / Σ SSE_b(S)`` is at least ``min_gain`` (2 %, the practical resolution) and (ii) a
one-sided t-test over the blocks rejects ``E[l_b] ≤ 0`` at ``α/K`` (Bonferroni over the ``K`` candidates of the
step, α = 1 %). Overfitting a candidate to noise makes ``l_b`` slightly negative on held-out data, so the null
case stays clean.

**Ties.** A significant runner-up whose paired block log-ratio differences against the best are not significant
(one-sided t-test, 5 %) explains the same held-out variance within the test's resolution: it is reported as tied
("X or Y") and the simpler one (fewer parameters) is the one added; the others stay candidates for later steps.
A candidate that lowers the weighted error but raises the unweighted held-out SSE counts as no gain.

**Noise.** Torque noise cannot shrink a held-out error. After the deterministic steps, an unmodelled
``torque_noise`` is reported when the remaining residual is white (Ljung–Box and state R²) and its variance
exceeds the noise the model already predicts. Encoder noise *can* be predicted: its signature is the change of the
modelled torque when the measured motion is de-noised (``EncoderNoiseCandidate``). Elasticity leaves τ_J exact for
a link-side position sensor; it is tested as the deflection a motor-side position sensor would miss
(``ElasticityCandidate``).

Confidence intervals come from the Jacobian of the fit (``σ² (JᵀWJ)⁻¹``) inflated by ``N / N_eff``, the
effective sample size of the autocorrelated residual (Bartlett), i.e. 95 % CI = ``± 1.96 σ_θ``.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from scipy import linalg, optimize, signal, stats

from proprio.description import RobotDescription
from proprio.dynamics import inverse_dynamics
from proprio.identification.gap_localisation import peak_orders
from proprio.identification.regressor import PARAMS_PER_JOINT, parameter_names, regressor
from proprio.recording import Recording, validate_recording
from proprio.systems.joint_effects import EFFECTS, JointEffect, MotionSignals

__all__ = ["SimModel", "GapData", "Candidate", "EffectCandidate", "RigidBodyCandidate", "PayloadCandidate",
           "SignalLagCandidate", "Step", "Attribution", "NoiseFinding", "ResidualStructure", "candidate_set",
           "attribute", "signals_of", "NOISE_EFFECTS", "DiagnosisError"]

NOISE_EFFECTS = ("torque_noise", "encoder_noise")
MIN_BLOCKS = 20
MIN_BLOCK_S = 0.5
MAX_FIT_SAMPLES = 4000


class DiagnosisError(ValueError):
    """Bad input to the gap diagnosis; the message names the offending argument."""


# ---------------------------------------------------------------------------------------------------------------
# the simulation model and the data
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SimModel:
    """A simulation model: rigid-body description (+ its viscous/Coulomb friction, if it has any, applied link-side)
    and the joint effects it already simulates. ``predict`` is the deterministic τ_J it expects [N·m]; noise
    effects contribute nothing to the prediction, only to the expected residual variance."""
    robot: RobotDescription
    effects: tuple[JointEffect, ...] = ()

    @classmethod
    def of(cls, model: "SimModel | RobotDescription") -> "SimModel":
        return model if isinstance(model, SimModel) else cls(model)

    @classmethod
    def from_names(cls, robot: RobotDescription, names: Sequence[str] = ()) -> "SimModel":
        """The model with the named library effects at their default parameters."""
        bad = [k for k in names if k not in EFFECTS]
        if bad:
            raise DiagnosisError(f"effects: unknown effect(s) {bad}; the library has {sorted(EFFECTS)}")
        return cls(robot, tuple(EFFECTS[k](robot.n) for k in names))

    @property
    def effect_names(self) -> set[str]:
        names = {e.name for e in self.effects}
        if self.robot.has_friction:
            names.add("viscous_coulomb")
        return names

    def predict(self, s: MotionSignals) -> np.ndarray:
        """Deterministic τ_J [N·m]: rigid body + link-side friction/effects, then sensor effects applied to that
        link-side torque (never to the measured one: a fit must not see the measurement's own noise)."""
        return self.predict_parts(s)[1]

    def predict_parts(self, s: MotionSignals) -> tuple[np.ndarray, np.ndarray]:
        """``(link-side torque, sensor output)`` the model predicts, each ``[N,n]`` N·m."""
        tau = inverse_dynamics(self.robot, s.q, s.qd, s.qdd)
        if self.robot.has_friction:
            tau = tau + np.asarray(self.robot.friction_viscous) * s.qd \
                + np.asarray(self.robot.friction_coulomb) * np.sign(s.qd)
        for eff in self.effects:
            if eff.place != "sensor":
                tau = tau + eff.torque(s)
        s_link = s.with_tau(tau)
        out = tau.copy()
        for eff in self.effects:
            if eff.place == "sensor" and eff.name not in NOISE_EFFECTS:
                out = out + eff.torque(s_link)
        return tau, out

    def noise_variance(self, s: MotionSignals, seed: int = 0) -> np.ndarray:
        """Variance per joint [(N·m)²] of the torque the model's noise effects add (0 without noise effects)."""
        var = np.zeros(self.robot.n)
        rng = np.random.default_rng(seed)
        for eff in self.effects:
            if eff.name == "torque_noise":
                var += np.var(eff.torque(s, rng=rng), axis=0)
        return var


def signals_of(rec: Recording) -> MotionSignals:
    """Motion signals of a Recording (its own q̇, q̈ when present; otherwise the effect library's derivative
    filter, which needs the recording to be longer than the filter — a clear error says so)."""
    return MotionSignals.from_recording(rec)


@dataclass
class GapData:
    """One set of recordings (training or held-out) prepared for the diagnosis: motion signals, measured τ, the
    model residual ``e``, block labels for the held-out test and a cache of candidate designs."""
    recordings: list[Recording]
    signals: list[MotionSignals]
    tau: list[np.ndarray]
    tau_sim: list[np.ndarray]
    e: list[np.ndarray]
    fit_index: list[np.ndarray]
    cache: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def build(cls, model: SimModel, recs: Sequence[Recording], trim_s: float, role: str) -> "GapData":
        sigs, taus, sims, es, idx = [], [], [], [], []
        total = sum(r.n_samples for r in recs)
        stride = max(1, int(math.ceil(total / MAX_FIT_SAMPLES)))
        for k, rec in enumerate(recs):
            try:
                s = signals_of(rec)
            except ValueError as exc:
                raise DiagnosisError(f"{role} recording {k}: {exc}") from exc
            link, sim = model.predict_parts(s)
            s = s.with_tau(link)          # candidates scale/load with the modelled, not the measured, torque
            keep = (rec.t >= rec.t[0] + trim_s) & (rec.t <= rec.t[-1] - trim_s)
            if keep.sum() < 10:
                raise DiagnosisError(f"{role} recording {k}: {rec.n_samples} samples ({rec.duration:.2f} s) leave "
                                     f"nothing after trimming {trim_s} s of filter start-up at each end")
            sigs.append(s)
            taus.append(rec.tau)
            sims.append(sim)
            es.append(rec.tau - sim)
            idx.append(np.flatnonzero(keep)[::stride] if role == "training" else np.flatnonzero(keep))
        return cls(list(recs), sigs, taus, sims, es, idx)

    def stack(self, arrays: Sequence[np.ndarray]) -> np.ndarray:
        """Concatenate per-recording arrays ``[N_k, ...]`` at the kept samples."""
        return np.concatenate([a[i] for a, i in zip(arrays, self.fit_index)])

    @property
    def residual(self) -> np.ndarray:
        return self.stack(self.e)

    def blocks(self, n_blocks: int) -> np.ndarray:
        """Block label per kept sample: contiguous time blocks, never straddling two recordings."""
        sizes = np.array([len(i) for i in self.fit_index], dtype=float)
        per = np.maximum(2, np.round(n_blocks * sizes / sizes.sum())).astype(int)
        out, base = [], 0
        for m, k in zip(sizes.astype(int), per):
            out.append(base + np.minimum((np.arange(m) * k) // m, k - 1))
            base += k
        return np.concatenate(out)


# ---------------------------------------------------------------------------------------------------------------
# candidates
# ---------------------------------------------------------------------------------------------------------------
class Candidate:
    """Something that may explain part of the residual. Linear ones provide ``design(data) -> [M, n, p]`` (at the
    data's kept samples); nonlinear ones ``torque(theta, data) -> [M, n]``, ``starts``, ``bounds``."""
    name: str = ""
    linear: bool = True
    place: str = ""

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


class EffectCandidate(Candidate):
    """A joint effect of the twin's library. Linear effects are fitted through their own ``regressor``; nonlinear
    ones start from the library defaults with every torque-amplitude parameter (default 0) set to a fraction of
    the residual's RMS per joint (two starts)."""
    AMPLITUDE_KEYS = ("static", "saturation", "amplitude", "offset")

    def __init__(self, name: str, n: int, keys: Sequence[str] | None = None, label: str | None = None,
                 **settings: Any):
        self.name = label or name
        self.effect = name
        self.proto: JointEffect = EFFECTS[name](n, **settings)
        self.linear = bool(self.proto.linear)
        self.place = self.proto.place
        all_keys = list(type(self.proto).parameters)
        self._keys = list(keys) if keys else all_keys
        self._cols = np.concatenate([np.arange(n) + n * all_keys.index(k) for k in self._keys])
        self._n = n

    def param_names(self) -> list[str]:
        return [f"{k}[{j + 1}]" for k in self._keys for j in range(self._n)]

    def design(self, data: GapData) -> np.ndarray:
        return data.stack([self.proto.regressor(s)[..., self._cols] for s in data.signals])

    def torque(self, theta: np.ndarray, data: GapData) -> np.ndarray:
        eff = self.proto.with_vector(np.asarray(theta, dtype=float))
        return data.stack([eff.torque(s) for s in data.signals])

    def starts(self, data: GapData) -> list[np.ndarray]:
        v = np.asarray(self.proto.vector(), dtype=float).reshape(len(self._keys), self._n)
        scale = np.sqrt((data.residual ** 2).mean(axis=0))
        out = []
        for f in (1.0, 0.3):
            x = v.copy()
            for i, k in enumerate(self._keys):
                if k in self.AMPLITUDE_KEYS and not np.any(x[i]):
                    x[i] = f * scale
            out.append(x.reshape(-1))
        return out

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.proto.bounds()
        return np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)

    def joint_of_param(self, n: int) -> np.ndarray:
        return np.tile(np.arange(n), len(self._keys))


def ripple_candidate(n: int, train: "GapData", max_order: float = 400.0) -> EffectCandidate:
    """The library's ripple ``A sin(h·N·q + φ)`` with its order ``h·N`` per joint set to the peak of the training
    residual's order spectrum (the ripple is linear once its order is known; the order is found, not assumed)."""
    q = train.stack([s.q for s in train.signals])
    qd = train.stack([s.qd for s in train.signals])
    orders = peak_orders(train.residual, q, qd, max_order=max_order, min_order=10.0)
    harmonic = 2.0
    return EffectCandidate("ripple", n, gear_ratio=orders / harmonic, harmonic=harmonic)


class EncoderNoiseCandidate(Candidate):
    """Position-sensor noise: the residual is the model's error from noisy q (and q̇, q̈ derived from it). Its
    signature is ``d_j = τ_sim(smoothed motion)_j − τ_sim(raw motion)_j`` (zero-phase low-pass at ``cutoff_hz``,
    well above arm motion and below encoder noise); the fitted share ``c_j`` should be ≈ 1 where it is real."""
    name = "encoder_noise"
    place = "sensor"

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
    link torque, its derivatives by finite differences of its 5 Hz zero-phase low-pass). With a link-side position sensor elasticity leaves
    τ_J = τ_rbd(q, q̇, q̈) exact and cannot show in this residual (``systems/joint_effects.Elasticity``)."""
    name = "elasticity"
    place = "motor"

    def __init__(self, model: "SimModel", accel: float = 1.0):
        self.model, self.accel = model, accel

    def param_names(self) -> list[str]:
        return [f"compliance[{j + 1}]" for j in range(self.model.robot.n)]

    def design(self, data: GapData) -> np.ndarray:
        out = []
        for s in data.signals:
            n, tau = s.n, s.tau
            rate = 1.0 / float(np.median(np.diff(s.t)))
            smooth = signal.sosfiltfilt(signal.butter(2, min(5.0, 0.2 * rate), fs=rate, output="sos"), tau, axis=0)
            tau_d = np.gradient(smooth, s.t, axis=0)
            tau_dd = np.gradient(tau_d, s.t, axis=0)
            cols = np.empty(s.q.shape + (n,))
            for k in range(n):
                # directional derivative of τ_rbd along the deflection (τ_k, τ̇_k, τ̈_k)·c_k of joint k
                h = 1e-3 / max(float(np.abs(tau[:, k]).max()), 1e-9)
                dirs = [np.zeros_like(s.q) for _ in range(3)]
                dirs[0][:, k], dirs[1][:, k], dirs[2][:, k] = h * tau[:, k], h * tau_d[:, k], h * tau_dd[:, k]
                plus = inverse_dynamics(self.model.robot, s.q + dirs[0], s.qd + dirs[1], s.qdd + self.accel * dirs[2])
                minus = inverse_dynamics(self.model.robot, s.q - dirs[0], s.qd - dirs[1], s.qdd - self.accel * dirs[2])
                cols[:, :, k] = -(plus - minus) / (2 * h)
            out.append(cols)
        return data.stack(out)

    def joint_of_param(self, n: int) -> np.ndarray:
        return -np.ones(n, dtype=int)


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

    def _inertial(self, data: GapData) -> np.ndarray:
        keep = np.array([k % PARAMS_PER_JOINT < 10 for k in range(PARAMS_PER_JOINT * self.robot.n)])
        return data.stack([regressor(self.robot, s.q, s.qd, s.qdd)[..., keep] for s in data.signals])

    def param_names(self) -> list[str]:
        return self._names

    def design(self, data: GapData) -> np.ndarray:
        return self._inertial(data)[..., self.columns]


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

    def design(self, data: GapData) -> np.ndarray:
        n = self.robot.n
        c0 = PARAMS_PER_JOINT * (n - 1)
        out = []
        for s in data.signals:
            y = regressor(self.robot, s.q, s.qd, s.qdd)[..., c0:c0 + 10]
            out.append(np.concatenate([y[..., :1] + y[..., 1:4] @ self.p_f[:, None], y[..., 1:4] @ self.r_f,
                                       y[..., 4:10]], axis=-1))
        return data.stack(out)


class SignalLagCandidate(Candidate):
    """A first-order lag of time constant ``T_j`` [s] between the modelled and the measured torque (a causal
    filter in the torque channel): ``e ≈ LP_T(τ_sim) − τ_sim`` with ``LP_T`` the exactly discretised first-order
    low-pass. Nonlinear in ``T``, one parameter per joint."""
    name = "signal_lag"
    place = "sensor"
    linear = False

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


def candidate_set(model: SimModel, train: GapData, names: Sequence[str] | None = None) -> list[Candidate]:
    """All deterministic candidates the model lacks (or only ``names``, which must be among them)."""
    n = model.robot.n
    present = model.effect_names
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
    available["rigid_body"] = lambda: RigidBodyCandidate(model.robot, train)
    available["payload"] = lambda: PayloadCandidate(model.robot)
    available["signal_lag"] = lambda: SignalLagCandidate(n)
    if names is not None:
        unknown = [k for k in names if k not in available and k != "torque_noise"]
        if unknown:
            why = [f"{k} (already in the model)" if k in present else f"{k} (unknown)" for k in unknown]
            raise DiagnosisError(f"candidates: cannot test {', '.join(why)}; available: {sorted(available)}")
        chosen = [k for k in names if k in available]
    else:
        chosen = list(available)
    if not chosen:
        raise DiagnosisError("candidates: no candidate effects left to test — the model already has every effect "
                             "of the library (or only noise effects were requested)")
    return [available[k]() for k in chosen]


# ---------------------------------------------------------------------------------------------------------------
# fitting
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class _Fit:
    thetas: dict[str, np.ndarray]
    cov: dict[str, np.ndarray]


def _wlstsq(a: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted LS of ``y [M,n] ≈ a [M,n,p] θ`` with joint weights ``w [n]`` by the normal equations of the
    column-scaled problem (eigen-decomposition, directions below 1e-10 of the largest dropped); returns θ and
    (AᵀWA)⁺."""
    sw = np.sqrt(w)
    aw = (a * sw[None, :, None]).reshape(-1, a.shape[-1])
    yw = (y * sw[None, :]).reshape(-1)
    scale = np.linalg.norm(aw, axis=0)
    scale[scale == 0] = 1.0
    g = (aw.T @ aw) / np.outer(scale, scale)
    lam, vec = np.linalg.eigh(g)
    keep = lam > 1e-10 * max(lam.max(), 1e-300)
    g_inv = (vec[:, keep] / lam[keep]) @ vec[:, keep].T
    theta = g_inv @ ((aw.T @ yw) / scale)
    return theta / scale, g_inv / np.outer(scale, scale)


def _fit_nonlinear(cand: Candidate, target: np.ndarray, data: GapData, w: np.ndarray,
                   starts: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Bounded nonlinear LS of one candidate on ``target [M,n]``; returns θ and (JᵀWJ)⁺ at the optimum.

    The Jacobian is by forward differences, grouped: parameters that act on different joints are perturbed
    together (one torque evaluation per parameter kind instead of per parameter)."""
    sw = np.sqrt(w)
    lo, hi = cand.bounds()
    n = target.shape[1]
    jp = cand.joint_of_param(n)
    if np.all(jp >= 0):
        kinds = len(jp) // n
        groups = [np.arange(k * n, (k + 1) * n) for k in range(kinds)] if len(jp) == kinds * n else \
            [np.array([i]) for i in range(len(jp))]
    else:
        groups = [np.array([i]) for i in range(len(jp))]

    def model(theta):
        return cand.torque(theta, data)

    def resid(theta):
        return ((target - model(theta)) * sw).reshape(-1)

    def jac(theta):
        base = model(theta)
        out = np.zeros((target.size, len(theta)))
        for grp in groups:
            h = 1e-6 * np.maximum(np.abs(theta[grp]), 1e-3)
            step_up = np.where(theta[grp] + h <= hi[grp], h, -h)
            th = theta.copy()
            th[grp] += step_up
            d = (model(th) - base) * sw                       # [M, n]
            for i, gi in enumerate(grp):
                col = np.zeros_like(d)
                if jp[gi] >= 0:
                    col[:, jp[gi]] = d[:, jp[gi]]
                else:
                    col = d
                out[:, gi] = -col.reshape(-1) / step_up[i]
        return out

    best = None
    for x0 in starts:
        x0 = np.asarray(x0, dtype=float).copy()
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        x0 = np.clip(x0, lo + 1e-6 * span * np.isfinite(lo), hi - 1e-6 * span * np.isfinite(hi))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = optimize.least_squares(resid, x0, jac=jac, bounds=(lo, hi), x_scale="jac", max_nfev=40,
                                         method="trf", tr_solver="exact")
        if best is None or sol.cost < best.cost:
            best = sol
    j = np.asarray(best.jac)
    return best.x, np.linalg.pinv(j.T @ j, rcond=1e-10)


def _fit_separable(cand: Candidate, target: np.ndarray, data: GapData, w: np.ndarray,
                   starts: list[np.ndarray], iters: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Bounded Levenberg–Marquardt for a candidate whose parameters act joint by joint (every library effect):
    the problem splits into one small ``K``-parameter problem per joint, solved for all joints at once (one torque
    evaluation per iterate and per parameter kind for the forward-difference Jacobian; steps accepted per joint).
    Returns θ and the block-diagonal (JᵀWJ)⁻¹."""
    lo, hi = cand.bounds()
    n = target.shape[1]
    k_kinds = cand.n_params // n
    lo, hi = lo.reshape(k_kinds, n), hi.reshape(k_kinds, n)
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)

    def clip(th):
        return np.clip(th, lo + 1e-9 * span * np.isfinite(lo), hi - 1e-9 * span * np.isfinite(hi))

    def model(th):
        return cand.torque(th.reshape(-1), data)

    def jacobian(th, base):
        jac = np.empty(target.shape + (k_kinds,))
        for k in range(k_kinds):
            h = 1e-6 * np.maximum(np.abs(th[k]), 1e-3)
            h = np.where(th[k] + h <= hi[k], h, -h)
            t2 = th.copy()
            t2[k] += h
            jac[:, :, k] = (model(t2) - base) / h
        return jac

    best_th, best_cost = None, None
    for x0 in starts:
        th = clip(np.asarray(x0, dtype=float).reshape(k_kinds, n).copy())
        pred = model(th)
        cost = ((target - pred) ** 2).sum(axis=0)
        lam = np.full(n, 1e-3)
        for _ in range(iters):
            jac = jacobian(th, pred)
            r = target - pred
            a = np.einsum("mjk,mjl->jkl", jac, jac)
            g = np.einsum("mjk,mj->jk", jac, r)
            d = np.einsum("jkk->jk", a) + 1e-12
            step = np.linalg.solve(a + lam[:, None, None] * d[:, :, None] * np.eye(k_kinds), g[..., None])[..., 0]
            th_new = clip(th + step.T)
            pred_new = model(th_new)
            cost_new = ((target - pred_new) ** 2).sum(axis=0)
            ok = cost_new < cost
            th = np.where(ok[None, :], th_new, th)
            pred = np.where(ok[None, :], pred_new, pred)
            gain = np.where(ok, (cost - cost_new) / np.maximum(cost, 1e-300), 0.0)
            cost = np.where(ok, cost_new, cost)
            lam = np.where(ok, lam / 3.0, lam * 4.0)
            if np.all((gain < 1e-6) & (ok | (lam > 1e6))):
                break
        if best_cost is None:
            best_th, best_cost = th.copy(), cost.copy()
        else:
            better = cost < best_cost
            best_th = np.where(better[None, :], th, best_th)
            best_cost = np.where(better, cost, best_cost)
    jac = jacobian(best_th, model(best_th))
    a = np.einsum("mjk,mjl->jkl", jac, jac) * w[:, None, None]
    cov = np.zeros((cand.n_params, cand.n_params))
    for j in range(n):
        idx = np.arange(k_kinds) * n + j
        cov[np.ix_(idx, idx)] = np.linalg.pinv(a[j], rcond=1e-10)
    return best_th.reshape(-1), cov


def _fit(cands: list[Candidate], data: GapData, w: np.ndarray, init: dict[str, np.ndarray],
         sweeps: int = 3) -> _Fit:
    """Joint fit of ``cands`` to the training residual: linear candidates exactly (one stacked LS), nonlinear ones
    by back-fitting (each on what the others leave), ``sweeps`` rounds."""
    e = data.residual
    lin = [c for c in cands if c.linear]
    nl = [c for c in cands if not c.linear]
    a = np.concatenate([c.cached_design(data) for c in lin], axis=-1) if lin else None
    thetas = {c.name: init.get(c.name, c.starts(data)[0]) for c in nl}
    torques = {c.name: c.torque(thetas[c.name], data) if c.name in init else np.zeros_like(e) for c in nl}
    cov: dict[str, np.ndarray] = {}
    for _ in range(sweeps if nl else 1):
        lin_pred = np.zeros_like(e)
        if lin:
            beta, inv = _wlstsq(a, e - sum(torques.values(), np.zeros_like(e)), w)
            lin_pred = a @ beta
            k = 0
            for c in lin:
                thetas[c.name] = beta[k:k + c.n_params]
                cov[c.name] = inv[k:k + c.n_params, k:k + c.n_params]
                k += c.n_params
        for c in nl:
            others = lin_pred + sum((t for k, t in torques.items() if k != c.name), np.zeros_like(e))
            starts = ([thetas[c.name]] if c.name in init else []) + c.starts(data)
            fitter = _fit_separable if np.all(c.joint_of_param(e.shape[1]) >= 0) else _fit_nonlinear
            thetas[c.name], cov[c.name] = fitter(c, e - others, data, w, starts)
            torques[c.name] = c.torque(thetas[c.name], data)
            init = {**init, c.name: thetas[c.name]}
    return _Fit(thetas, cov)


def _predict(cands: list[Candidate], fit: _Fit, data: GapData) -> np.ndarray:
    out = np.zeros_like(data.residual)
    for c in cands:
        out += c.cached_design(data) @ fit.thetas[c.name] if c.linear else c.torque(fit.thetas[c.name], data)
    return out


def _n_eff_factor(r: np.ndarray, max_lag: int = 200) -> float:
    """N / N_eff of an autocorrelated residual (Bartlett: 1 + 2 Σ ρ_k up to the first non-positive ρ), the
    factor by which the white-noise covariance of a fit understates its true covariance (averaged over joints)."""
    fac = []
    for col in r.T:
        x = col - col.mean()
        v = float(x @ x)
        if v <= 0:
            continue
        s = 1.0
        for k in range(1, min(max_lag, len(x) // 4)):
            rho = float(x[:-k] @ x[k:]) / v
            if rho <= 0:
                break
            s += 2 * rho
        fac.append(s)
    return float(np.mean(fac)) if fac else 1.0


# ---------------------------------------------------------------------------------------------------------------
# greedy forward selection
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class Step:
    """One accepted step: ``name`` (``tied`` lists the candidates that explain the same held-out variance),
    relative held-out gain, t statistic over blocks, per-joint held-out RMSE after the step [N·m], fitted
    parameters with 95 % CI half-widths."""
    name: str
    tied: list[str]
    gain: float
    t_stat: float
    rmse_after: np.ndarray
    params: dict[str, tuple[np.ndarray, np.ndarray, list[str]]]


@dataclass
class NoiseFinding:
    """Unmodelled white noise: ``rms [n]`` N·m per joint (0 on joints where the residual is structured or within
    the model's own noise)."""
    name: str
    rms: np.ndarray
    explanation: str


@dataclass
class ResidualStructure:
    """What stays unexplained on the held-out data: per joint RMSE [N·m], Ljung–Box p-value (lags 1..20 of the
    residual decimated to ≥ 0.05 s spacing), held-out R² of the residual against state features, and a verdict."""
    rmse: np.ndarray
    ljung_box_p: np.ndarray
    r2_state: np.ndarray
    structured_time: np.ndarray
    structured_state: np.ndarray

    @property
    def white(self) -> bool:
        return not (self.structured_time.any() or self.structured_state.any())


@dataclass
class Attribution:
    """Result of :func:`attribute`."""
    joint_names: list[str]
    steps: list[Step]
    ranking: list[dict[str, Any]]
    rmse_before: np.ndarray
    signal_rms: np.ndarray
    residual: ResidualStructure
    noise: list[NoiseFinding]
    candidates: list[str]
    holdout_e: list[np.ndarray]
    holdout_pred: list[np.ndarray]
    holdout_t: list[np.ndarray]

    @property
    def selected(self) -> list[str]:
        return [s.name for s in self.steps] + [f.name for f in self.noise]

    def top(self, k: int) -> list[str]:
        """The first ``k`` distinct names in attribution order, tied alternatives included after each step."""
        out: list[str] = []
        for s in self.steps:
            for nm in [s.name] + s.tied:
                if nm not in out:
                    out.append(nm)
        for f in self.noise:
            if f.name not in out:
                out.append(f.name)
        return out[:k]


def _block_gain(r_s: np.ndarray, delta: np.ndarray, w: np.ndarray, blk: np.ndarray, n_blk: int):
    """Per block the log-ratio ``l_b = log(SSE_S,b / SSE_S+c,b)`` of the weighted squared residual (scale-free, so
    blocks of fast reaches and slow exploration weigh alike), and the overall relative gain ``G``."""
    before = np.bincount(blk, weights=((r_s ** 2) * w).sum(axis=1), minlength=n_blk)
    after = np.bincount(blk, weights=(((r_s - delta) ** 2) * w).sum(axis=1), minlength=n_blk)
    lb = np.log(np.maximum(before, 1e-300) / np.maximum(after, 1e-300))
    return lb, 1.0 - float(after.sum()) / max(float(before.sum()), 1e-300)


def _t_stat(x: np.ndarray) -> float:
    sd = float(np.std(x, ddof=1))
    if sd <= 0:
        return math.inf if x.mean() > 0 else -math.inf
    return float(x.mean() / (sd / math.sqrt(len(x))))


def _residual_structure(r_h: np.ndarray, r_tr: np.ndarray, train: GapData, hold: GapData,
                        rate: float) -> ResidualStructure:
    n = r_h.shape[1]
    step = max(1, int(round(0.05 * rate)))
    lb = np.ones(n)
    for j in range(n):
        ps = []
        for e_k, idx in zip(_split(r_h[:, j], hold), hold.fit_index):
            x = e_k[::step] - e_k[::step].mean()
            m = min(20, len(x) // 5)
            if m < 2 or x @ x <= 0:
                continue
            rho = np.array([x[:-k] @ x[k:] for k in range(1, m + 1)]) / (x @ x)
            q = len(x) * (len(x) + 2) * np.sum(rho ** 2 / (len(x) - np.arange(1, m + 1)))
            ps.append(stats.chi2.sf(q, m))
        lb[j] = min(ps) if ps else 1.0

    def feats(data: GapData) -> np.ndarray:
        f = [np.concatenate([s.q, s.qd, np.sign(s.qd), s.qdd, np.sin(s.q), np.cos(s.q)], axis=1)
             for s in data.signals]
        f = data.stack(f)
        return np.concatenate([np.ones((len(f), 1)), f], axis=1)

    ft, fh = feats(train), feats(hold)
    r2 = np.zeros(n)
    for j in range(n):
        coef, *_ = np.linalg.lstsq(ft, r_tr[:, j], rcond=1e-8)
        res = r_h[:, j] - fh @ coef
        r2[j] = 1.0 - float(res @ res) / max(float(r_h[:, j] @ r_h[:, j]), 1e-300)
    return ResidualStructure(np.sqrt((r_h ** 2).mean(axis=0)), lb, r2, lb < 0.01, r2 > 0.05)


def _split(x: np.ndarray, data: GapData) -> list[np.ndarray]:
    sizes = np.cumsum([len(i) for i in data.fit_index])[:-1]
    return np.split(x, sizes)


def attribute(model: SimModel | RobotDescription, train_recs: Sequence[Recording],
              holdout_recs: Sequence[Recording], candidates: Sequence[str] | None = None, trim_s: float = 0.5,
              alpha: float = 0.01, min_gain: float = 0.02, max_steps: int = 6,
              progress: Callable[[str], None] | None = None) -> Attribution:
    """Greedy forward attribution of the residual ``τ_meas − τ_sim`` to candidate effects (module docstring).

    ``model``: the simulation model (a RobotDescription = rigid body + its friction, or a :class:`SimModel`);
    ``train_recs`` / ``holdout_recs``: Recordings of the same robot; ``candidates``: restrict to these names;
    ``trim_s``: seconds dropped at both ends of every recording (filter start-up). Raises :class:`DiagnosisError`
    on bad input (no recordings, joint-count mismatch, holdout too short for the block test, nothing to test)."""
    model = SimModel.of(model)
    n = model.robot.n
    if not train_recs or not holdout_recs:
        raise DiagnosisError("recordings: need at least one training and one held-out recording")
    for role, recs in (("training", train_recs), ("holdout", holdout_recs)):
        for k, r in enumerate(recs):
            if r.n_joints != n:
                raise DiagnosisError(f"{role} recording {k}: has {r.n_joints} joints but the model robot "
                                     f"'{model.robot.name}' has {n} (mismatched robots)")
            try:
                validate_recording(r, model.robot, source=f"{role} recording {k}")
            except ValueError as exc:
                raise DiagnosisError(f"{exc} (mismatched robots?)") from exc
    hold_len = min(r.duration for r in holdout_recs)
    need = MIN_BLOCKS * MIN_BLOCK_S / len(holdout_recs) + 2 * trim_s
    if sum(r.duration for r in holdout_recs) - 2 * trim_s * len(holdout_recs) < MIN_BLOCKS * MIN_BLOCK_S:
        raise DiagnosisError(f"holdout: {sum(r.duration for r in holdout_recs):.2f} s of held-out data is too short "
                             f"for the block test ({MIN_BLOCKS} blocks of {MIN_BLOCK_S} s after trimming {trim_s} s "
                             f"per end: ≥ {need:.1f} s per recording, shortest has {hold_len:.2f} s)")
    say = progress or (lambda msg: None)
    train = GapData.build(model, train_recs, trim_s, "training")
    hold = GapData.build(model, holdout_recs, trim_s, "holdout")
    cands = candidate_set(model, train, candidates)
    e_tr, e_h = train.residual, hold.residual
    w = 1.0 / np.maximum((e_tr ** 2).mean(axis=0), 1e-12)
    held_s = sum(r.duration for r in holdout_recs) - 2 * trim_s * len(holdout_recs)
    n_blk = max(MIN_BLOCKS, int(held_s / MIN_BLOCK_S))
    blk = hold.blocks(n_blk)
    n_blk = int(blk.max()) + 1
    sig = np.sqrt((hold.stack(hold.tau) ** 2).mean(axis=0))
    rmse0 = np.sqrt((e_h ** 2).mean(axis=0))

    selected: list[Candidate] = []
    fit = _Fit({}, {})
    pred_h = np.zeros_like(e_h)
    steps: list[Step] = []
    ranking: list[dict[str, Any]] = []
    remaining = list(cands)
    while remaining and len(steps) < max_steps:
        r_s = e_h - pred_h
        scored = []
        for c in remaining:
            say(f"step {len(steps) + 1}: fitting {c.name}")
            f_c = _fit(selected + [c], train, w, fit.thetas, sweeps=1 if c.linear else 2)
            delta = _predict(selected + [c], f_c, hold) - pred_h
            db, g = _block_gain(r_s, delta, w, blk, n_blk)
            raw = float((r_s ** 2).sum() - ((r_s - delta) ** 2).sum())    # unweighted held-out SSE change
            scored.append((c, f_c, db, g if raw > 0 else min(g, 0.0), _t_stat(db)))
        k_test = len(scored)
        t_crit = stats.t.ppf(1 - alpha / k_test, n_blk - 1)
        if not steps:
            ranking = [{"name": c.name, "gain": g, "t": t, "n_params": c.n_params,
                        "significant": bool(g >= min_gain and t >= t_crit)} for c, _, _, g, t in scored]
            ranking.sort(key=lambda x: -x["gain"])
        sig_ok = [x for x in scored if x[3] >= min_gain and x[4] >= t_crit]
        if not sig_ok:
            break
        sig_ok.sort(key=lambda x: -x[3])
        best = sig_ok[0]
        t_tie = stats.t.ppf(0.95, n_blk - 1)
        group = [best] + [x for x in sig_ok[1:] if _t_stat(best[2] - x[2]) < t_tie]
        group.sort(key=lambda x: (x[0].n_params, -x[3]))
        chosen = group[0]
        c, f_c = chosen[0], chosen[1]
        selected.append(c)
        remaining = [x for x in remaining if x is not c]     # tied partners stay: they may still add later
        fit = _fit(selected, train, w, f_c.thetas, sweeps=3) if any(not s.linear for s in selected) else f_c
        pred_h = _predict(selected, fit, hold)
        r_tr = e_tr - _predict(selected, fit, train)
        infl = _n_eff_factor(r_tr)
        s2 = float(((r_tr ** 2) * w).sum()) / max(r_tr.size - sum(s.n_params for s in selected), 1)
        params = {s.name: (fit.thetas[s.name], 1.96 * np.sqrt(np.maximum(np.diag(fit.cov[s.name]), 0) * s2 * infl),
                           s.param_names()) for s in selected}
        steps.append(Step(c.name, [g[0].name for g in group[1:]], chosen[3], chosen[4],
                          np.sqrt(((e_h - pred_h) ** 2).mean(axis=0)), params))
        say(f"step {len(steps)}: added {c.name} (held-out gain {100 * chosen[3]:.1f} %)")

    r_h = e_h - pred_h
    r_tr = e_tr - _predict(selected, fit, train)
    rate = float(np.median([r.rate_hz for r in holdout_recs]))
    structure = _residual_structure(r_h, r_tr, train, hold, rate)
    noise = _noise_findings(model, structure, hold, r_h)
    return Attribution(model.robot.joint_names, steps, ranking, rmse0, sig, structure, noise,
                       [c.name for c in cands], _split(e_h, hold), _split(pred_h, hold),
                       [r.t[i] for r, i in zip(hold.recordings, hold.fit_index)])


def _noise_findings(model: SimModel, structure: ResidualStructure, hold: GapData,
                    r_h: np.ndarray) -> list[NoiseFinding]:
    """Unmodelled noise: the remaining residual is white in time and state, and larger than the model's own noise
    (variance ratio beyond the χ² 99.9 % bound of the sample variance, plus 20 % of slack)."""
    present = model.effect_names
    out = []
    white_j = ~(structure.structured_time | structure.structured_state)
    if not white_j.any():
        return out
    expected = np.mean([model.noise_variance(s) for s in hold.signals], axis=0)
    var = (r_h ** 2).mean(axis=0)
    m = len(r_h)
    bound = expected * 1.2 * stats.chi2.ppf(0.999, m) / m + 1e-12
    excess = white_j & (var > bound)
    if not excess.any():
        return out
    if "torque_noise" not in present and "torque_noise" in EFFECTS:
        out.append(NoiseFinding("torque_noise", np.where(excess, np.sqrt(np.maximum(var - expected, 0.0)), 0.0),
                                "white residual above the model's noise level"))
    return out
