"""The experiment that decides between confusable effects (issue #25), and the re-diagnosis with its recording.

**Design.** For a tied set (:class:`~proprio.diagnosis.selection.ambiguity.AmbiguitySet`) every member has been fitted
in the named effect's place on the diagnosed data. A short motion separates them when the torques the members predict
on it differ by more than the noise *after* each is refitted to the other's prediction (a difference one member
can fit away tells nothing). The motion is chosen and tuned from a family, each member starting and ending at the
set's ``home`` configuration (a configuration the robot visited):

* ``triangles``: slow triangles of growing amplitude (hysteresis saturates with the travel since a reversal,
  Coulomb friction does not; lost motion lives in the first degree);
* ``sweeps``: back-and-forth sweeps at several constant speeds (viscous against Coulomb friction);
* ``dwell_reverse``: small reversals at several gravity loads (load-dependent friction or hysteresis against a
  sensor gain error);
* ``poses``: slow and fast reaches between distant poses (payload against rigid-body error).

Score of a member: for every ordered pair (A, B) of the set, B (with the context effects) is refitted to A's
prediction on the motion and ``z = RMS((τ_A − τ_B*)/σ) · sqrt(T / 0.5 s)`` (σ [n] the held-out residual RMS the
diagnosis left, T the motion's duration; ≈ the separation in units of the noise over independent half-second
blocks); the member's score is the smallest z over the pairs and the best member is kept. A *confounded pair*
(:func:`confounded_pairs`: two effects the selection both named, whose torques can take each other's place) is
scored on the even mixture of the two members' predictions instead: each member alone (with the context) is refitted
to it, and z is the smallest misfit — a motion on which neither alone can mimic the mixture lets the joint fit divide
the shared torque between them (either alone can absorb the other's level elsewhere: a hysteresis whose travel shrinks
mimics a Coulomb step). Below
:data:`MIN_SCORE` no motion of the family separates the set: it says so (a payload, for instance, is inside the
rigid-body error's span for every motion).

**The trajectory** is two mirrored passes of the chosen motion (offsets negated), each ≤ 30 s, so ≤ 60 s in all;
every phase starts and ends at rest within a fraction of the joint velocity/acceleration limits
(:func:`proprio.systems.trajectories.time_parameterize`), amplitudes stay 10 % inside the position limits, and it
is sampled for self- and environment collisions (:class:`proprio.collision.CollisionChecker`; a colliding motion is
shrunk, then dropped). It is written with :func:`~proprio.systems.trajectories.save_trajectory`, the format
``proprio trajectory`` writes, with ``meta.split_s`` (the time between the passes).

**Re-diagnosis.** The recording of the trajectory is cut at ``split_s`` (:func:`split_passes`): the first pass joins
the training recordings, the mirrored second one the held-out ones, so the held-out test itself sees the motion
that separates the set. :func:`resolution` compares the tied sets before with the diagnosis after.

**The joint re-fit** (:func:`joint_refit`). The selection fits its named effects by back-fitting: each nonlinear one
on what the others leave, a few sweeps. Where several of them share one torque — the demo's Coulomb friction, a lost
motion of the Coulomb amplitude and a 6° hysteresis all flip with the direction of motion — back-fitting moves along
the ridge between them by small steps and stops far from the optimum (measured on the demo's twin excitation, 45 s at
100 Hz: joint 1 Coulomb +95 %, hysteresis saturation −68 %, at a weighted cost 70 above the twin's own sensor-effect
parameters, 1527 against 1457).
The joint re-fit puts every named effect whose parameters act joint by joint into one problem per joint
(:class:`JointSet`: all their parameters of that joint at once, Levenberg–Marquardt) and alternates only with the
effects that couple joints (rigid body, payload): on the same data it reaches 1458 with joint 1's Coulomb −18 % and
saturation +8 % (README, "Confusable effects").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from proprio.collision import CollisionChecker
from proprio.conditioning import ConditionedSignals
from proprio.diagnosis.selection.ambiguity import TIE_SHARE, AmbiguitySet, tied_sets
from proprio.diagnosis.candidates.base import Candidate
from proprio.diagnosis.data import GapData, SimModel
from proprio.diagnosis.fitting import Fit, fit_candidates, predict_candidates
from proprio.recording import Recording
from proprio.signals import MotionSignals
from proprio.systems.trajectories import (Phase, check_limits, sample_trajectory, save_trajectory,
                                          time_parameterize)

__all__ = ["Experiment", "Resolution", "design_experiment", "split_passes", "resolution", "confounded_pairs",
           "pair_set", "JointSet", "joint_refit", "MIN_SCORE", "PASS_S", "CONFOUND_CORRELATION"]

PASS_S = 30.0            # s, each of the two mirrored passes
MIN_SCORE = 3.0          # separation (noise units over half-second blocks) below which nothing decides
SCORE_RATE_HZ = 50.0     # Hz, the motion sampled for the predictions
BLOCK_S = 0.5
CONFOUND_CORRELATION = 0.8   # two named effects whose held-out torques correlate this much share their parameters


@dataclass
class Experiment:
    """The chosen motion for the tied ``members``: its family and label, its score (``score``, the smallest
    refitted separation over the pairs; ``raw_score`` before refitting), the trajectory (two mirrored passes,
    ``split_s`` [s] between them), every family member's ``(family, label, raw, refitted)`` score, the limit check
    (:func:`~proprio.systems.trajectories.check_limits`) and whether it decides (score ≥ :data:`MIN_SCORE`)."""
    members: list[str]
    family: str
    label: str
    score: float
    raw_score: float
    trajectory: Any = field(repr=False)
    split_s: float
    duration: float
    scores: list[tuple[str, str, float, float]]
    limits: dict[str, float]
    robot: str
    pair: bool = False

    @property
    def decides(self) -> bool:
        return self.score >= MIN_SCORE

    @property
    def worth_running(self) -> bool:
        """It decides, or ``members`` is a confounded pair: both effects stay named and the joint fit gains from the
        motion that shows their mixture best even where one alone could still mimic it within the noise."""
        return self.decides or self.pair

    def meta(self) -> dict[str, Any]:
        return {"robot": self.robot, "purpose": f"separate {' vs '.join(self.members)}", "family": self.family,
                "label": self.label, "score": self.score, "raw_score": self.raw_score, "split_s": self.split_s,
                "passes": [[0.0, self.split_s], [self.split_s, self.duration]], "limits": self.limits,
                "collision_checked": True, "confounded_pair": self.pair}

    def save(self, path: str | Path) -> Path:
        """The trajectory file (``proprio trajectory``'s format, :func:`save_trajectory`) with :meth:`meta`."""
        return save_trajectory(path, self.trajectory, self.meta())

    def text(self) -> str:
        who = " vs ".join(self.members)
        if self.pair:
            return (f"{' and '.join(self.members)} (both named, their levels trade off): {self.family} {self.label}, "
                    f"{self.duration:.0f} s in two mirrored passes (split at {self.split_s:.1f} s), shows their "
                    f"mixture apart from either alone by {self.score:.1f} noise units after refitting "
                    f"({self.raw_score:.1f} before); the re-diagnosis fits both jointly on the old and the new data.")
        if not self.decides:
            return (f"{who}: no motion of the family separates them beyond the noise (best {self.family} "
                    f"{self.label}, separation {self.score:.1f} < {MIN_SCORE:g} noise units after refitting): on "
                    "joint torques alone they are not identifiable; decide by other means (a weighing, a sensor "
                    "calibration).")
        return (f"{who}: {self.family} {self.label}, {self.duration:.0f} s in two mirrored passes (split at "
                f"{self.split_s:.1f} s), separates them by {self.score:.1f} noise units after refitting "
                f"({self.raw_score:.1f} before).")


def _legs(q0: np.ndarray, offsets: Sequence[np.ndarray], vf: float) -> list[Phase]:
    """Rest-to-rest straight phases q0 → q0+o_1 → … → q0 at velocity fraction ``vf``."""
    pts = [q0] + [q0 + o for o in offsets] + [q0]
    return [Phase(np.stack([a, b]), vf, min(1.0, 2 * vf), "experiment") for a, b in zip(pts[:-1], pts[1:])
            if np.any(a != b)]


def _family(q0: np.ndarray, room: np.ndarray, n: int) -> list[tuple[str, str, Any]]:
    """``(family, label, build)`` per member: ``build(sign)`` gives its units (each a list of phases from ``q0`` back
    to ``q0``) with the offsets times ``sign`` (−1: the mirrored pass). ``room [n]`` rad: the largest offset per
    joint (a member the room clips to the same motion as an earlier one of its family is left out)."""
    out = []
    alt = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)

    def amp(a: float) -> np.ndarray:
        return np.minimum(a, room)

    for a_max in (3.0, 8.0, 15.0):
        for vf in (0.03, 0.1):
            a = amp(math.radians(a_max))

            def tri(sign, a=a, vf=vf):
                return [_legs(q0, [sign * f * a, -sign * f * a], vf) for f in (0.08, 0.15, 0.25, 0.4, 0.6, 0.8, 1.0)]
            out.append(("triangles", f"up to {a_max:g}° at {100 * vf:g} % speed", tri))
    for a_deg in (10.0, 25.0):
        a = amp(math.radians(a_deg))

        def sweep(sign, a=a):
            return [_legs(q0, [sign * a, -sign * a], vf) for vf in (0.04, 0.1, 0.25, 0.5)]
        out.append(("sweeps", f"±{a_deg:g}° at 4–50 % speed", sweep))
    for load_deg in (15.0, 35.0):
        lo = amp(math.radians(load_deg)) * alt
        small = amp(math.radians(2.0))

        def dwell(sign, lo=lo, small=small):
            units = []
            for p in (sign * lo, -sign * lo):
                units.append(_legs(q0, [p, p + small, p - small, p + small, p - small, p], 0.05))
            return units
        out.append(("dwell_reverse", f"±2° reversals at loads of ±{load_deg:g}°", dwell))
    for reach_deg in (30.0, 60.0):
        r = amp(math.radians(reach_deg)) * alt
        if reach_deg > 30.0 and np.allclose(r, amp(math.radians(30.0)) * alt):
            continue

        def poses(sign, r=r):
            return [_legs(q0, [sign * r, -sign * r], vf) for vf in (0.1, 0.4)]
        out.append(("poses", f"reaches of ±{reach_deg:g}°", poses))
    return out


def _passes(model: SimModel, build, q0: np.ndarray, pass_s: float = PASS_S) -> tuple[Any, float] | None:
    """The two mirrored passes of a family member as one trajectory (units dropped from the end until a pass fits
    ``pass_s`` [s], default :data:`PASS_S`), and the time between them; ``None`` if not even one unit fits."""
    robot = model.robot
    first, second = build(1.0), build(-1.0)
    k = len(first)
    while k > 0:
        one = time_parameterize([p for u in first[:k] for p in u], robot)
        if one.duration <= pass_s:
            both = time_parameterize([p for u in first[:k] + second[:k] for p in u], robot)
            return both.trajectory, one.duration
        k -= 1
    return None


def _prediction_data(model: SimModel, traj: Any) -> GapData:
    """The planned motion as prediction data: exact q, q̇, q̈ at :data:`SCORE_RATE_HZ` (no noise, nothing to
    condition), its ``tau`` the model's torque."""
    t, q, qd, qdd = sample_trajectory(traj, SCORE_RATE_HZ)
    n = q.shape[1]
    sim = model.predict(MotionSignals(t, q, qd, qdd))
    zero = np.zeros(n)
    cs = ConditionedSignals(t, q, qd, qdd, sim, np.ones(len(t), dtype=bool), SCORE_RATE_HZ,
                            np.full(n, SCORE_RATE_HZ / 4), zero, 1.0, zero, zero, "planned", False, np.ones(n),
                            ["the planned motion (exact q, q̇, q̈)"])
    return GapData.build(model, [cs], [np.ones(len(t), dtype=bool)], "holdout")


def _separation(aset: AmbiguitySet, data: GapData, refit: bool, mixed: bool = False) -> float:
    """Smallest separation z over the ordered member pairs (module docstring) on ``data``; ``mixed``: over the
    members, each refitted to the even mixture of the members' predictions (a confounded pair, module docstring)."""
    ctx = [aset.candidates[k] for k in aset.context]
    pred = {m: predict_candidates(ctx + [aset.candidates[m]], aset.fits[m], data) for m in aset.members}
    scale = np.sqrt(max(float(data.times[0][-1] - data.times[0][0]), BLOCK_S) / BLOCK_S)
    sigma = np.maximum(aset.sigma, 1e-6)
    mix = sum(pred.values()) / len(pred)
    orders = [(None, b) for b in aset.members] if mixed else \
        [(a, b) for a in aset.members for b in aset.members if a != b and (refit or a < b)]
    best = math.inf
    for a, b in orders:
        goal = mix if a is None else pred[a]
        other = pred[b]
        if refit:
            target = replace(data, e=[goal])             # the designs depend on the motion only: cache shared
            cs = ctx + [aset.candidates[b]]
            f = fit_candidates(cs, target, aset.weights, dict(aset.fits[b].thetas),
                               sweeps=3 if any(not c.linear for c in cs) else 1)
            other = predict_candidates(cs, f, target)
        z = float(np.sqrt(np.mean(((goal - other) / sigma) ** 2))) * scale
        best = min(best, z)
    return best


def design_experiment(model: SimModel, aset: AmbiguitySet, checker: CollisionChecker | None = None,
                      refit_top: int = 3, families: Sequence[str] | None = None,
                      mixed: bool = False, pass_s: float = PASS_S) -> Experiment | None:
    """The motion of the family (module docstring) that best separates the tied set ``aset``, within the limits and
    collision-checked (``checker``: default the robot's self-collision checker); ``None`` when ``aset`` is not tied
    or no member fits the limits without a collision. The ``refit_top`` best members by raw separation are scored
    with the refit; ``families``: only these kinds of motion (``"triangles"``, ``"sweeps"``, ``"dwell_reverse"``,
    ``"poses"``; default all). ``mixed``: ``aset`` is a confounded pair (:func:`pair_set`) — both effects stay, so
    the motion must show the even mixture of the two apart from either one alone (module docstring). ``pass_s`` [s]:
    the longest pass (≤ :data:`PASS_S`; a shorter experiment keeps the first, smallest units of each motion)."""
    if not aset.tied:
        return None
    if not 0.0 < pass_s <= PASS_S:
        raise ValueError(f"design_experiment: pass_s = {pass_s:g} s outside (0, {PASS_S:g}] s")
    robot = model.robot
    checker = checker or CollisionChecker(robot)
    q0 = aset.home
    room = 0.9 * np.minimum(robot.upper - q0, q0 - robot.lower)
    room = np.maximum(room, 0.0)
    scored = []
    unknown = set(families or ()) - {"triangles", "sweeps", "dwell_reverse", "poses"}
    if unknown:
        raise ValueError(f"design_experiment: families {sorted(unknown)} unknown; valid: triangles, sweeps, "
                         "dwell_reverse, poses")
    for fam, label, build in _family(q0, room, robot.n):
        if families is not None and fam not in families:
            continue
        made = None
        for shrink in (1.0, 0.5):
            made = _passes(model, lambda sign, b=build, s=shrink: [[Phase(q0 + s * (p.waypoints - q0),
                                                                         p.velocity_fraction,
                                                                         p.acceleration_fraction, p.kind)
                                                                   for p in u] for u in b(sign)], q0, pass_s)
            if made is None:
                continue
            qs = sample_trajectory(made[0], 10.0)[1]
            if not checker.any_collision(qs):
                break
            made = None
        if made is None:
            continue
        data = _prediction_data(model, made[0])
        scored.append([fam, label, made, data, _separation(aset, data, refit=False, mixed=mixed), None])
    if not scored:
        return None
    scored.sort(key=lambda x: -x[4])
    for row in scored[:refit_top]:
        row[5] = _separation(aset, row[3], refit=True, mixed=mixed)
    best = max(scored[:refit_top], key=lambda x: x[5])
    traj, split = best[2]
    return Experiment(list(aset.members), best[0], best[1], float(best[5]), float(best[4]), traj, float(split),
                      float(traj.end_time() - traj.start_time()),
                      [(r[0], r[1], float(r[4]), float("nan") if r[5] is None else float(r[5])) for r in scored],
                      check_limits(traj, robot, 200.0), robot.name, pair=mixed)


def confounded_pairs(sets: Sequence[AmbiguitySet]) -> list[tuple[AmbiguitySet, str]]:
    """Named effects whose parameters trade off: ``(set of s, t)`` for two effects ``s`` and ``t`` that the selection
    both named, where ``t`` swapped into ``s``'s place explains at least
    :data:`~proprio.diagnosis.selection.ambiguity.TIE_SHARE` of its held-out gain with held-out torques correlated ≥
    :data:`CONFOUND_CORRELATION`, but is not tied with it. The block test then prefers ``s`` and keeps both, yet the
    data cannot say how the shared torque divides between them: ``s`` takes ``t``'s level (the demo's mixture:
    hysteresis fitted with the Coulomb level, Coulomb ≈ 0). Each unordered pair once."""
    named = {a.effect for a in sets}
    seen: set[frozenset] = set()
    out = []
    for a in sets:
        for alt in a.alternatives:
            key = frozenset((a.effect, alt.name))
            if (alt.name in named and not alt.tied and alt.share >= TIE_SHARE
                    and alt.correlation >= CONFOUND_CORRELATION and key not in seen):
                seen.add(key)
                out.append((a, alt.name))
    return out


def pair_set(aset: AmbiguitySet, other: str, train: GapData) -> AmbiguitySet:
    """The confounded pair (:func:`confounded_pairs`) of ``aset.effect`` and the named ``other`` as a two-member set
    for :func:`design_experiment`: each member fitted alone in the pair's place, with the named effects outside the
    pair, on ``train`` (the diagnosis' training data, :meth:`GapData.build`; started from the joint fit)."""
    ctx = [k for k in aset.context if k != other]
    cands = [aset.candidates[k] for k in ctx]
    init = dict(aset.fits[aset.effect].thetas)
    fits = {}
    for m in (aset.effect, other):
        cs = cands + [aset.candidates[m]]
        fits[m] = fit_candidates(cs, train, aset.weights, {k: v for k, v in init.items() if k in ctx or k == m},
                                 sweeps=3 if any(not c.linear for c in cs) else 1)
    alt = next(a for a in aset.alternatives if a.name == other)
    return replace(aset, members=[aset.effect, other], alternatives=[replace(alt, tied=True)], context=ctx, fits=fits,
                   joint_gain=float("nan"), shared=float("nan"), exclusive={})


class JointSet(Candidate):
    """Several candidates whose parameters act joint by joint (:func:`separable`), fitted as one nonlinear candidate:
    its parameters are the members' in order (each laid out kind by kind, joint by joint), its torque [N·m] the sum
    of theirs, so the fitter solves one small problem per joint with every member's parameters of that joint
    (module docstring, "The joint re-fit"). A member's torque is kept for its last parameters, so a finite-difference
    step in one member's parameters evaluates that member only."""
    linear = False

    def __init__(self, members: Sequence[Candidate]):
        self.members = list(members)
        self.name = "+".join(c.name for c in self.members)
        self._sizes = [c.n_params for c in self.members]
        self._last: dict[int, tuple[bytes, np.ndarray]] = {}
        self._data: GapData | None = None

    def param_names(self) -> list[str]:
        return [f"{c.name}.{p}" for c in self.members for p in c.param_names()]

    def split(self, theta: np.ndarray) -> list[np.ndarray]:
        """``theta`` cut into the members' parameter vectors."""
        return np.split(np.asarray(theta, dtype=float), np.cumsum(self._sizes)[:-1])

    def torque(self, theta: np.ndarray, data: GapData) -> np.ndarray:
        if data is not self._data:
            self._data, self._last = data, {}
        out = np.zeros_like(data.residual)
        for k, (c, th) in enumerate(zip(self.members, self.split(theta))):
            key = th.tobytes()
            if k not in self._last or self._last[k][0] != key:
                self._last[k] = (key, c.cached_design(data) @ th if c.linear else c.torque(th, data))
            out += self._last[k][1]
        return out

    def starts(self, data: GapData) -> list[np.ndarray]:
        """One start: the members' library starts (a linear member at 0)."""
        return [np.concatenate([np.zeros(c.n_params) if c.linear else c.starts(data)[0] for c in self.members])]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = zip(*(c.bounds() for c in self.members))
        return np.concatenate(lo), np.concatenate(hi)

    def joint_of_param(self, n: int) -> np.ndarray:
        return np.concatenate([c.joint_of_param(n) for c in self.members])


def separable(cand: Candidate, n: int) -> bool:
    """Whether every parameter of ``cand`` acts on one joint, laid out kind by kind over the ``n`` joints (every
    library effect; not the rigid body or a payload, which couple joints)."""
    k, rem = divmod(cand.n_params, n)
    return rem == 0 and k > 0 and np.array_equal(cand.joint_of_param(n), np.tile(np.arange(n), k))


def joint_refit(cands: Sequence[Candidate], data: GapData, w: np.ndarray, init: dict[str, np.ndarray],
                sweeps: int = 3) -> Fit:
    """``cands`` fitted to ``data``'s residual with every joint-separable one (:func:`separable`) in one
    :class:`JointSet` — per joint, all their parameters in one problem — alternating with the others
    (:func:`~proprio.diagnosis.fitting.fit_candidates`, ``sweeps`` rounds; module docstring, "The joint re-fit").
    ``w [n]`` joint weights, ``init`` start parameters by name (e.g. the selection's fit). Returns the parameters
    (and covariance blocks) by candidate name, as :func:`~proprio.diagnosis.fitting.fit_candidates` does."""
    n = data.residual.shape[1]
    sep = [c for c in cands if separable(c, n)]
    if len(sep) < 2:
        return fit_candidates(list(cands), data, w, init, sweeps=sweeps)
    js = JointSet(sep)
    rest = [c for c in cands if c not in sep]
    lib = js.split(js.starts(data)[0])
    x0 = np.concatenate([np.asarray(init.get(c.name, x), dtype=float) for c, x in zip(sep, lib)])
    start = {c.name: init[c.name] for c in rest if c.name in init and not c.linear}
    fit = fit_candidates(rest + [js], data, w, {**start, js.name: x0}, sweeps=sweeps)
    thetas = {k: v for k, v in fit.thetas.items() if k != js.name}
    cov = {k: v for k, v in fit.cov.items() if k != js.name}
    edges = np.cumsum([0] + [c.n_params for c in sep])
    for c, th, a, b in zip(sep, js.split(fit.thetas[js.name]), edges[:-1], edges[1:]):
        thetas[c.name] = th
        cov[c.name] = fit.cov[js.name][a:b, a:b]
    return Fit(thetas, cov)


def split_passes(rec: Recording, split_s: float | None = None) -> tuple[Recording, Recording]:
    """The recording of a designed experiment cut into its two passes at ``split_s`` [s] after its start (default:
    the middle of its time span; the passes are of equal length)."""
    t = rec.t - rec.t[0]
    cut = 0.5 * float(t[-1]) if split_s is None else float(split_s)
    k = int(np.searchsorted(t, cut))
    if not 0 < k < rec.n_samples:
        raise ValueError(f"experiment recording: split at {cut:.2f} s lies outside its {t[-1]:.2f} s")
    return rec.slice(0, k), rec.slice(k, rec.n_samples)


@dataclass
class Resolution:
    """A tied set before the experiment and what the diagnosis with the experiment's recording names of it:
    ``named`` (the members named as effects now), ``still_tied`` (members still tied with a named one), ``text``."""
    members: list[str]
    named: list[str]
    still_tied: list[str]
    text: str

    @property
    def resolved(self) -> bool:
        return not self.still_tied

    def to_dict(self) -> dict[str, Any]:
        return {"members": self.members, "named": self.named, "still_tied": self.still_tied,
                "resolved": self.resolved, "text": self.text}


def resolution(before: Sequence[AmbiguitySet], after: Sequence[AmbiguitySet]) -> list[Resolution]:
    """For each tied set of ``before``: which of its members the diagnosis with the experiment names (``after``: its
    ambiguity sets) and whether they are still tied with one another."""
    out = []
    for b in tied_sets(before):
        mem = set(b.members)
        named = [a.effect for a in after if a.effect in mem]
        still = sorted({m for a in after if a.effect in mem for m in a.members if m in mem and m != a.effect})
        who = " and ".join(b.members)
        if still:
            text = (f"{who}: still tied after the experiment ({', '.join(named)} named, "
                    f"{', '.join(still)} explains as much) — the data still cannot tell them apart.")
        elif named:
            text = f"{who}: resolved — the diagnosis with the experiment names {' and '.join(named)}" + \
                (f", not {', '.join(sorted(mem - set(named)))}." if mem - set(named) else ".")
        else:
            text = f"{who}: with the experiment none of them is named any more."
        out.append(Resolution(list(b.members), named, still, text))
    return out
