"""Joint trajectories: waypoints → smooth, limit-respecting ``PiecewisePolynomial``, and the Drake sources that play
them (a planned trajectory, or a Recording's measured q(t)).

Time parameterisation (used for RFMA, §4.3, and for any waypoint list)
----------------------------------------------------------------------
A path is a sequence of :class:`Phase` objects; each phase is a list of joint-space waypoints traversed at one
*relative speed* ``velocity_fraction`` (and ``acceleration_fraction``) of the robot's joint limits, starting and
ending at rest — the way the thesis' KUKA controller executes a waypoint list with a set relative speed (§4.3).
Consecutive phases share their junction waypoint. For each phase:

1. **Geometry.** The waypoints ``w_0 … w_m`` become a C² curve ``P(σ)`` of the waypoint index σ ∈ [0, m]
   (a natural cubic spline; a 2-waypoint phase is the straight joint-space line, i.e. *joint-wise linear*).
2. **Timing.** σ(t) follows a smooth trapezoid: the rate σ̇ rises from 0 to a cruise rate σ̇_c along a quintic
   smoothstep (σ̈ and σ⃛ continuous, σ̈ zero at both ends of the ramp), cruises, and falls back to 0. With
   ``v_j, a_j`` the joint limits and ``α_v, α_a`` the phase's fractions, q̇_j = P'_j σ̇ and
   q̈_j = P''_j σ̇² + P'_j σ̈, so
   ``σ̇_c = min(α_v min_j v_j / max|P'_j|, sqrt(α_a min_j a_j / (2 max|P''_j|)))`` and the ramp's peak
   ``σ̈ = min_j (α_a a_j − max|P''_j| σ̇_c²) / max|P'_j|`` keep every joint inside ``α_v v_j`` and ``α_a a_j``
   (the acceleration bound may make σ̇_c lower than the velocity fraction alone would: a sinusoid of small
   amplitude cannot be run at a high speed without a high acceleration).
3. **Spline in time.** q(t) = P(σ(t)) is C² (P is C², σ is C²). It is sampled at knots every ``knot_dt`` seconds
   and one global clamped cubic spline (zero velocity at both ends) is fitted through all knots; it is handed to
   Drake as ``PiecewisePolynomial.CubicHermite`` with the spline's own knot slopes, which reproduces that C² spline
   exactly. The knots pass exactly through every phase's end waypoint; between knots the interpolation error is
   O(knot_dt⁴) in position (≈1e-6 rad at 20 ms) and O(knot_dt³) in velocity, so the junctions are at rest up to
   ≈1e-3 rad/s. The limits are verified on the result by dense sampling in the tests (:func:`check_limits`).

Why not TOPP-RA: a time-optimal schedule rides every limit, whereas RFMA asks for a *chosen* relative speed per
phase; the closed-form schedule above is exact, cheap (vectorised over knots) and reproducible.

Drake sources
-------------
* :func:`AddTrajectorySource` wraps Drake's C++ ``TrajectorySource`` (``output_derivative_order=2``) with
  Demultiplexers in a small Diagram whose output ports are named ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²]
  and ``state`` = [q; qd] (the desired-state input of Drake's ``InverseDynamicsController``).
* :func:`AddReplaySource` plays a Recording's measured q(t) (first-order hold, or a shape-preserving cubic).
"""
from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial, Trajectory
from scipy.interpolate import CubicSpline

from proprio.description import RobotDescription
from proprio.io import atomic_path

__all__ = ["Phase", "TimedPath", "time_parameterize", "sample_positions", "sample_trajectory", "check_limits",
           "JointTrajectorySource", "AddTrajectorySource", "AddReplaySource", "replay_trajectory", "save_trajectory",
           "load_trajectory", "TrajectoryFileError", "truncate_trajectory"]

TRAJECTORY_FORMAT = "proprio-trajectory/v1"


class TrajectoryFileError(ValueError):
    """A trajectory file is missing, malformed or inconsistent; the message names the offending field."""


# ---------------------------------------------------------------------------------------------------------------
# time parameterisation
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Phase:
    """Waypoints ``[m+1, n]`` [rad] traversed from rest to rest at ``velocity_fraction`` of the joint velocity
    limits (and at most ``acceleration_fraction`` of the acceleration limits). ``kind`` is a free label
    (RFMA uses ``"reach"`` and ``"explore"``)."""
    waypoints: np.ndarray
    velocity_fraction: float
    acceleration_fraction: float
    kind: str = "path"


@dataclass(frozen=True)
class TimedPath:
    """A time-parameterised path: the Drake trajectory q(t) [rad] plus where each phase starts and ends.

    ``phase_times[k]`` and ``phase_times[k+1]`` [s] bound phase ``k``; ``phase_kinds[k]`` is its label."""
    trajectory: PiecewisePolynomial
    phase_times: np.ndarray
    phase_kinds: tuple[str, ...]

    @property
    def duration(self) -> float:
        return float(self.trajectory.end_time() - self.trajectory.start_time())

    def meta(self) -> dict[str, Any]:
        """JSON-able description of the phases (for :func:`save_trajectory`)."""
        return {"phase_times": [float(x) for x in self.phase_times], "phase_kinds": list(self.phase_kinds)}


@dataclass(frozen=True)
class _Schedule:
    """σ(t) of one phase: smooth-trapezoid rate profile with ramp time ``t_ramp``, cruise rate ``rate``."""
    length: float     # σ range [waypoint intervals]
    rate: float       # cruise σ̇ [1/s]
    t_ramp: float     # ramp duration [s]

    @property
    def duration(self) -> float:
        return self.t_ramp + self.length / self.rate

    def sigma(self, t: np.ndarray) -> np.ndarray:
        """σ(t) for t ∈ [0, duration]: ramps integrate the smoothstep rate ``rate·(10τ³ − 15τ⁴ + 6τ⁵)``."""
        t = np.clip(t, 0.0, self.duration)
        ta, v = self.t_ramp, self.rate
        if ta == 0.0:
            return v * t

        def ramp(tt: np.ndarray) -> np.ndarray:            # ∫_0^tt v (10τ³ − 15τ⁴ + 6τ⁵) dt, τ = tt/ta
            tau = tt / ta
            return v * ta * tau ** 4 * (2.5 - 3.0 * tau + tau ** 2)

        t_end = self.duration
        return np.where(t < ta, ramp(t),
                        np.where(t <= t_end - ta, 0.5 * v * ta + v * (t - ta), self.length - ramp(t_end - t)))


def _schedule(curve: CubicSpline | None, delta: np.ndarray | None, length: float, vel: np.ndarray, acc: np.ndarray,
              alpha_v: float, alpha_a: float) -> _Schedule:
    """Cruise rate and ramp of one phase from the curve's derivative bounds (module docstring, step 2)."""
    if curve is None:                              # straight line σ ∈ [0, 1]: P' = Δq, P'' = 0
        d1, d2 = np.abs(delta), np.zeros_like(delta)
    else:                                          # bound |P'|, |P''| on a grid 8× finer than the waypoints
        s = np.linspace(0.0, length, int(8 * length) + 1)
        d1 = np.abs(curve(s, 1)).max(axis=0)
        d2 = np.abs(curve(s, 2)).max(axis=0)
    moving = d1 > 0.0
    if not moving.any():
        raise ValueError("phase does not move: all its waypoints are equal")
    rate = alpha_v * np.min(vel[moving] / d1[moving])
    curved = d2 > 0.0
    if curved.any():
        rate = min(rate, math.sqrt(alpha_a * np.min(acc[curved] / (2.0 * d2[curved]))))
    ramp_acc = np.min((alpha_a * acc[moving] - d2[moving] * rate ** 2) / d1[moving])
    t_ramp = 1.875 * rate / ramp_acc               # peak σ̈ of the smoothstep ramp = 1.875 rate / t_ramp
    if rate * t_ramp > length:                     # too short to reach cruise: scale the rate down (same ramp acc)
        rate = math.sqrt(length * ramp_acc / 1.875)
        t_ramp = 1.875 * rate / ramp_acc
    return _Schedule(length=length, rate=rate, t_ramp=t_ramp)


def time_parameterize(phases: Sequence[Phase], desc: RobotDescription, knot_dt: float = 0.02) -> TimedPath:
    """Turn waypoint phases into one C² joint trajectory within the fractions of ``desc``'s limits.

    Args:
        phases: the phases in order; each phase's first waypoint must equal the previous phase's last one.
        desc: robot description (``velocity_limits`` [rad/s], ``acceleration_limits`` [rad/s²]).
        knot_dt: spacing of the spline knots [s].
    Returns:
        :class:`TimedPath` starting at t = 0, exactly at rest at both ends and at rest at every phase junction up
        to the interpolation error (module docstring, step 3).
    """
    if not phases:
        raise ValueError("time_parameterize: no phases given")
    if not knot_dt > 0.0:
        raise ValueError(f"knot_dt must be > 0 s, got {knot_dt}")
    vel, acc = desc.velocity_limits, desc.acceleration_limits
    if not np.all(np.isfinite(acc)):
        raise ValueError(f"robot '{desc.name}' has no finite acceleration limits; time parameterisation needs them")
    knots_t, knots_q, bounds = [np.zeros(1)], [np.asarray(phases[0].waypoints, float)[:1]], [0.0]
    t0 = 0.0
    for k, ph in enumerate(phases):
        w = np.asarray(ph.waypoints, dtype=float)
        if w.ndim != 2 or w.shape[1] != desc.n or w.shape[0] < 2:
            raise ValueError(f"phase {k}: waypoints must have shape [m+1>=2, {desc.n}], got {list(w.shape)}")
        if not (0.0 < ph.velocity_fraction <= 1.0 and 0.0 < ph.acceleration_fraction <= 1.0):
            raise ValueError(f"phase {k}: velocity/acceleration fractions must lie in (0, 1], got "
                             f"{ph.velocity_fraction}, {ph.acceleration_fraction}")
        if not np.allclose(w[0], knots_q[-1][-1], atol=1e-9):
            raise ValueError(f"phase {k}: first waypoint differs from the previous phase's last waypoint")
        if w.shape[0] == 2:
            curve, delta, length = None, w[1] - w[0], 1.0
        else:
            curve, delta, length = CubicSpline(np.arange(w.shape[0]), w, bc_type="natural"), None, w.shape[0] - 1.0
        sched = _schedule(curve, delta, length, vel, acc, ph.velocity_fraction, ph.acceleration_fraction)
        n_knots = max(4, int(math.ceil(sched.duration / knot_dt)))
        tk = np.linspace(0.0, sched.duration, n_knots + 1)[1:]
        sig = sched.sigma(tk)
        q = w[0] + np.outer(sig, delta) if curve is None else curve(sig)
        q[-1] = w[-1]                                   # land exactly on the phase's last waypoint
        knots_t.append(t0 + tk)
        knots_q.append(q)
        t0 += sched.duration
        bounds.append(t0)
    t = np.concatenate(knots_t)
    q = np.concatenate(knots_q)
    spline = CubicSpline(t, q, bc_type="clamped")       # C², zero velocity at both ends
    traj = PiecewisePolynomial.CubicHermite(t, q.T, spline(t, 1).T)
    return TimedPath(traj, np.asarray(bounds), tuple(ph.kind for ph in phases))


# ---------------------------------------------------------------------------------------------------------------
# sampling and checks
# ---------------------------------------------------------------------------------------------------------------
def truncate_trajectory(traj: PiecewisePolynomial, seconds: float) -> PiecewisePolynomial:
    """The first ``seconds`` [s] of ``traj`` in whole segments (ends at the first break at or after
    ``start + seconds``; the whole trajectory if it is shorter)."""
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    end = traj.start_time() + seconds
    if end >= traj.end_time():
        return traj
    return traj.slice(0, int(np.searchsorted(traj.get_segment_times(), end, side="left")))


def sample_positions(traj: Trajectory, rate_hz: float, t0: float | None = None,
                     t1: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``t [N]`` s and ``q [N,n]`` rad of ``traj`` sampled at ``rate_hz`` over [t0, t1] (default: its whole span), as
    :func:`sample_trajectory` samples them, without the derivatives."""
    if not rate_hz > 0.0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    t0 = traj.start_time() if t0 is None else float(t0)
    t1 = traj.end_time() if t1 is None else float(t1)
    t = t0 + np.arange(int(math.floor((t1 - t0) * rate_hz + 1e-9)) + 1) / rate_hz
    return t, traj.vector_values(t).T


def sample_trajectory(traj: Trajectory, rate_hz: float, t0: float | None = None,
                      t1: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sample ``traj`` at ``rate_hz`` over [t0, t1] (default: its whole span), vectorised in Drake's C++.

    Returns ``t [N]`` s, ``q [N,n]`` rad, ``qd [N,n]`` rad/s, ``qdd [N,n]`` rad/s².
    """
    t, q = sample_positions(traj, rate_hz, t0, t1)
    qd = traj.MakeDerivative(1).vector_values(t).T
    qdd = traj.MakeDerivative(2).vector_values(t).T
    return t, q, qd, qdd


def check_limits(traj: Trajectory, desc: RobotDescription, rate_hz: float = 1000.0) -> dict[str, float]:
    """Worst ratio of |q̇|, |q̈| to the limits and the worst position-limit excess over a dense sampling.

    Returns ``{"velocity": max_j max_t |q̇_j|/v_j, "acceleration": ..., "position_excess_rad": max(q−upper,
    lower−q)}``; a trajectory is inside the limits when the ratios are ≤ 1 and the excess is ≤ 0.
    """
    _, q, qd, qdd = sample_trajectory(traj, rate_hz)
    return {"velocity": float(np.max(np.abs(qd) / desc.velocity_limits)),
            "acceleration": float(np.max(np.abs(qdd) / desc.acceleration_limits)),
            "position_excess_rad": float(max(np.max(q - desc.upper), np.max(desc.lower - q)))}


# ---------------------------------------------------------------------------------------------------------------
# Drake sources
# ---------------------------------------------------------------------------------------------------------------
class JointTrajectorySource(Diagram):
    """Plays a joint trajectory q(t): Drake's C++ ``TrajectorySource`` (output_derivative_order=2) split by
    Demultiplexers. Output ports: ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²], ``state`` = [q; qd].
    After the trajectory's end the outputs hold its final value (zero derivatives)."""

    def __init__(self, trajectory: Trajectory, name: str = "trajectory"):
        super().__init__()
        n = trajectory.rows()
        b = DiagramBuilder()
        src = b.AddNamedSystem("source", TrajectorySource(trajectory, output_derivative_order=2,
                                                          zero_derivatives_beyond_limits=True))
        split = b.AddNamedSystem("split", Demultiplexer([n, n, n]))
        state = b.AddNamedSystem("state_split", Demultiplexer([2 * n, n]))
        b.Connect(src.get_output_port(), split.get_input_port())
        b.Connect(src.get_output_port(), state.get_input_port())
        for i, port in enumerate(("q", "qd", "qdd")):
            b.ExportOutput(split.get_output_port(i), port)
        b.ExportOutput(state.get_output_port(0), "state")
        b.BuildInto(self)
        self.set_name(name)
        self.num_joints = n

    def source(self) -> TrajectorySource:
        """The underlying Drake ``TrajectorySource`` (e.g. to ``UpdateTrajectory``)."""
        return self.GetSubsystemByName("source")


def AddTrajectorySource(builder: DiagramBuilder, trajectory: Trajectory,
                        name: str = "trajectory") -> JointTrajectorySource:
    """Add a :class:`JointTrajectorySource` playing ``trajectory`` (ports ``q``, ``qd``, ``qdd``, ``state``)."""
    return builder.AddSystem(JointTrajectorySource(trajectory, name=name))


def replay_trajectory(recording: Any, interpolation: str = "first_order_hold") -> PiecewisePolynomial:
    """A Recording's measured q(t) as a ``PiecewisePolynomial`` (time as recorded).

    ``interpolation``: ``"first_order_hold"`` (piecewise linear: the samples, nothing invented) or
    ``"cubic"`` (shape-preserving cubic, C¹: no overshoot between samples, velocity from the data).
    """
    t = np.asarray(recording.t, dtype=float)
    q = np.asarray(recording.q, dtype=float)
    if t.ndim != 1 or q.ndim != 2 or q.shape[0] != t.shape[0] or t.shape[0] < 2:
        raise ValueError(f"recording: need t [N>=2] and q [N,n], got {list(t.shape)} and {list(q.shape)}")
    if interpolation == "first_order_hold":
        return PiecewisePolynomial.FirstOrderHold(t, q.T)
    if interpolation == "cubic":
        return PiecewisePolynomial.CubicShapePreserving(t, q.T, zero_end_point_derivatives=False)
    raise ValueError(f"interpolation must be 'first_order_hold' or 'cubic', got {interpolation!r}")


def AddReplaySource(builder: DiagramBuilder, recording: Any, interpolation: str = "first_order_hold",
                    name: str = "replay") -> JointTrajectorySource:
    """Add a source replaying ``recording.q(t)`` (ports as :class:`JointTrajectorySource`; ``qd``/``qdd`` are the
    interpolant's derivatives: piecewise constant / zero for the first-order hold)."""
    return AddTrajectorySource(builder, replay_trajectory(recording, interpolation), name=name)


# ---------------------------------------------------------------------------------------------------------------
# files
# ---------------------------------------------------------------------------------------------------------------
def save_trajectory(path: str | Path, traj: PiecewisePolynomial, meta: dict[str, Any] | None = None) -> Path:
    """Save a piecewise-cubic trajectory as ``.npz`` (atomic): ``breaks [K]`` s, ``q [K,n]`` rad, ``qd [K,n]``
    rad/s (Hermite data at the breaks, exact for cubic segments) and ``meta`` (a JSON string).

    Raises ``ValueError`` if ``traj`` is not piecewise cubic (checked at the segment midpoints).
    """
    breaks = np.asarray(traj.get_segment_times(), dtype=float)
    q = traj.vector_values(breaks).T
    qd = traj.MakeDerivative(1).vector_values(breaks).T
    mid = 0.5 * (breaks[1:] + breaks[:-1])
    rebuilt = PiecewisePolynomial.CubicHermite(breaks, q.T, qd.T)
    scale = 1.0 + np.abs(q).max()
    if np.abs(rebuilt.vector_values(mid) - traj.vector_values(mid)).max() > 1e-9 * scale:
        raise ValueError("save_trajectory: only piecewise-cubic trajectories can be saved (Hermite form)")
    meta_json = json.dumps({"format": TRAJECTORY_FORMAT, **(meta or {})})
    path = Path(path)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez_compressed(tmp, breaks=breaks, q=q, qd=qd, meta=np.array(meta_json))
    return path


def load_trajectory(path: str | Path) -> tuple[PiecewisePolynomial, dict[str, Any]]:
    """Load a file written by :func:`save_trajectory`: ``(trajectory, meta)``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"trajectory file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("breaks", "q", "qd", "meta") if k not in z.files]
            if missing:
                raise TrajectoryFileError(f"{path}: not a proprio trajectory (missing {', '.join(missing)})")
            breaks, q, qd, meta_s = z["breaks"], z["q"], z["qd"], str(z["meta"])
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        if isinstance(exc, TrajectoryFileError):
            raise
        raise TrajectoryFileError(f"{path}: cannot read as .npz, truncated or corrupted ({exc})") from exc
    try:
        meta = json.loads(meta_s)
    except json.JSONDecodeError as exc:
        raise TrajectoryFileError(f"{path}: 'meta' is not valid JSON ({exc})") from exc
    fmt = meta.get("format") if isinstance(meta, dict) else None
    if fmt != TRAJECTORY_FORMAT:
        raise TrajectoryFileError(f"{path}: 'meta.format' is {fmt!r}, expected {TRAJECTORY_FORMAT!r}")
    if breaks.ndim != 1 or breaks.size < 2 or np.any(np.diff(breaks) <= 0) or not np.all(np.isfinite(breaks)):
        raise TrajectoryFileError(f"{path}: 'breaks' must be a strictly increasing finite vector")
    for name, a in (("q", q), ("qd", qd)):
        if a.ndim != 2 or a.shape[0] != breaks.size or not np.all(np.isfinite(a)):
            raise TrajectoryFileError(f"{path}: '{name}' must be finite with shape [{breaks.size}, n], "
                                      f"got {list(a.shape)}")
    return PiecewisePolynomial.CubicHermite(breaks, q.T, qd.T), meta
