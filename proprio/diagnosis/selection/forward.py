"""Which unmodelled effect causes the sim-to-real torque gap, and how far does it shrink? (DESIGN.md "Gap
diagnosis", steps 3–4.)

Candidates are every deterministic effect of the twin's joint-effect library (``proprio.effects``)
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

**Stand-ins.** A greedy step may take an effect that imitates one named later — Stribeck friction for viscous +
Coulomb friction that is not yet significant while a rigid-body error dominates the residual. After the forward
steps every named physical effect is scored in the context of all the others (its held-out gain when added last,
the rest refitted without it); one that adds less than ``min_gain`` there was a stand-in and is dropped (the lowest
first, the rest refitted, at most :data:`MAX_SUPERSEDED` times) — backward elimination after the forward steps.
:attr:`Attribution.superseded` says which effect was dropped, at which step it had been taken and what it added.
(Running the forward selection again without the stand-in would not do: the effects it stood in for may only become
significant together, as the rigid body and Coulomb friction of the gap benchmark's pair.)

**Position is not history.** Hysteresis, lost motion and pre-sliding friction depend on the motion's history (the
travel since the last reversal); a torque-sensor gain error on the measured torque. Along a trajectory both follow
where the arm is, so a torque of the configuration alone can pose as them
(:data:`~proprio.diagnosis.candidates.configuration.POSITION_MIMICS`). Such a candidate that wins a step is set aside
(:attr:`Attribution.position_only`; the hints then say which q the residual follows) when a configuration-only torque
(:class:`~proprio.diagnosis.candidates.configuration.ConfigurationCandidate`: ``1, q, sin q, cos q`` of the joint's
own angle — a spring ``k (q − q₀)``, a cable's ``sin q`` — on the joints where these columns explain a significant
part of the training residual beyond a constant: :func:`_configuration_joints`) explains at least as much of the
held-out residual as it does *and* it adds no significant held-out gain (``min_gain`` and the step's t bound) beyond
that torque. Both conditions: a configuration basis fitted on one motion can extrapolate poorly to another, so "adds
nothing beyond it" alone would also set aside a real effect whose held-out gain the basis' extrapolation error
swamps.

**Noise.** Torque noise cannot shrink a held-out error. After the deterministic steps, an unmodelled
``torque_noise`` is reported when the remaining residual is white (Ljung–Box and state R² agree:
:mod:`proprio.diagnosis.residual`) and its variance exceeds the noise the model already predicts, or — for a model
without torque noise, on a joint whose residual's structure lies within the conditioning's own error, where the
whiteness test cannot decide — when the raw τ's floor is white (:func:`proprio.diagnosis.residual.noise_findings`).
Encoder noise *can* be predicted: its signature is the change of the modelled torque when the measured motion is de-noised (``EncoderNoiseCandidate``, for a model without encoder noise).
Past the low-pass that signature is mostly unpredictable band-limited noise, so encoder noise is also compared by
*level*: the data's position-noise floor against the model's encoder noise (:mod:`proprio.diagnosis.encoder_floor`,
:attr:`Attribution.encoder`), a data-path finding (:attr:`Attribution.processing_findings`), never a cause.
Elasticity leaves τ_J exact for a link-side position sensor; it is tested as the deflection a motor-side position
sensor would miss (``ElasticityCandidate``).

**Time variation.** Before the selection the residual of all recordings is tested for dependence on the session
time (drift, warm-up, steps between sessions: :mod:`proprio.diagnosis.selection.time_variation`, reported in
``Attribution.time_variation``). When it is detected, the time-varying library effects join the candidates and every
static candidate is fitted with a time-trend nuisance, so that none (rigid body, payload) can win by fitting a trend.

Confidence intervals come from the Jacobian of the fit (``σ² (JᵀWJ)⁻¹``) inflated by ``N / N_eff``, the
effective sample size of the autocorrelated residual (Bartlett), i.e. 95 % CI = ``± 1.96 σ_θ``.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
from scipy import stats

from proprio.description import RobotDescription
from proprio.diagnosis.candidates.registry import candidate_set
from proprio.diagnosis.candidates.base import Candidate
from proprio.diagnosis.candidates.configuration import POSITION_MIMICS, ConfigurationCandidate, own_angle_columns
from proprio.conditioning import ConditionedSignals, ConditioningConfig, processing_torque_sigma
from proprio.diagnosis.data import (DIAGNOSIS_CONDITIONING, MIN_BLOCK_S, MIN_BLOCKS, Conditioned, GapData, SimModel,
                                    condition_recordings, session_motion)
from proprio.diagnosis.selection.ambiguity import ambiguity_sets
from proprio.diagnosis.attribution import Attribution, CrossValidation, PositionOnly, Step, Superseded, Undecided
from proprio.diagnosis.model_terms import missing_model_term
from proprio.diagnosis.selection.block_test import block_gain, n_eff_factor, t_stat
from proprio.diagnosis.encoder_floor import encoder_floor
from proprio.diagnosis.fitting import Fit, fit_candidates, predict_candidates
from proprio.diagnosis.residual import noise_findings, residual_structure, split_by_recording
from proprio.diagnosis.hints import find_hints, shifted_joints
from proprio.diagnosis.selection.time_variation import TimeTrendNuisance, TimeVariation, time_variation
from proprio.recording import Recording

__all__ = ["attribute", "attribute_conditioned"]

MAX_BLOCK_S = 2.0
MAX_SUPERSEDED = 3
"""The most stand-ins the backward check drops from one selection (module docstring, "Stand-ins")."""


def _correlation_time(model: SimModel, conditioned: Sequence[ConditionedSignals], keep: Sequence[np.ndarray],
                      session_s: Sequence[float]) -> float:
    """Correlation time [s] of the model residual (the model on the session clock ``session_s`` [s] per recording):
    the lag where its autocorrelation first falls below 1/e (FFT, median over joints and recordings)."""
    out = []
    for cs, kp, t0 in zip(conditioned, keep, session_s):
        e = (cs.tau - model.predict(session_motion(cs, t0)))[kp]
        e = e - e.mean(axis=0)
        m = len(e)
        spec = np.fft.rfft(e, n=2 * m, axis=0)
        acf = np.fft.irfft(np.abs(spec) ** 2, axis=0)[:m]
        acf = acf / np.maximum(acf[:1], 1e-300)
        below = acf < np.exp(-1.0)
        lag = np.where(below.any(axis=0), below.argmax(axis=0), m)
        out.extend(lag / cs.rate_hz)
    return float(np.median(out))


def _time_blocks(hold: GapData, block_s: float) -> np.ndarray:
    """Block label per kept held-out sample: consecutive ``block_s`` spans of each recording (a piece of a
    cross-validated recording is one block)."""
    out, base = [], 0
    for t in hold.times:
        k = np.zeros(len(t), dtype=int) if hold.pieces else np.floor((t - t[0]) / block_s).astype(int)
        out.append(base + k)
        base += int(k.max()) + 1
    lab = np.concatenate(out)
    return np.unique(lab, return_inverse=True)[1]


def attribute(model: SimModel | RobotDescription, train_recs: Sequence[Recording],
              holdout_recs: Sequence[Recording] = (), candidates: Sequence[str] | None = None,
              trim_s: float | None = None,
              alpha: float = 0.01, min_gain: float = 0.02, max_steps: int = 6,
              progress: Callable[[str], None] | None = None,
              conditioning: ConditioningConfig = DIAGNOSIS_CONDITIONING,
              plugins: Sequence[str | type] = ()) -> Attribution:
    """Greedy forward attribution of the residual ``τ_meas − τ_sim`` to candidate effects (module docstring).

    ``model``: the simulation model (a RobotDescription = rigid body + its friction, or a :class:`SimModel`);
    ``train_recs`` / ``holdout_recs``: Recordings of the same robot, conditioned by ``conditioning``
    (:mod:`proprio.conditioning`). Without ``holdout_recs`` the training recordings are cross-validated over time
    blocks (sized from the residual's correlation time): alternate blocks train and score, in two folds with the roles
    swapped, and the result reports how well the folds agree. ``candidates``: restrict to these names; ``plugins``:
    user-defined effects (plugin paths ``"package.module:Class"`` or ``JointEffect`` subclasses,
    :mod:`proprio.effects.plugins`) tested alongside the library candidates; ``trim_s``:
    seconds dropped at both ends of every recording (filter start-up; ``None``: each recording's default,
    :func:`proprio.diagnosis.data.default_trim_s`). Raises :class:`DiagnosisError` on bad input
    (no recordings, joint-count mismatch, too little data for the block test, nothing to test)."""
    model = SimModel.of(model)
    data = condition_recordings(model, train_recs, holdout_recs, conditioning, trim_s, progress)
    return attribute_conditioned(model, data, candidates, alpha, min_gain, max_steps, progress, plugins)


def attribute_conditioned(model: SimModel, data: Conditioned, candidates: Sequence[str] | None = None,
                          alpha: float = 0.01, min_gain: float = 0.02, max_steps: int = 6,
                          progress: Callable[[str], None] | None = None,
                          plugins: Sequence[str | type] = ()) -> Attribution:
    """:func:`attribute` on recordings conditioned once (:func:`~proprio.diagnosis.data.condition_recordings`): the
    diagnosis' route (:func:`proprio.diagnosis.route.diagnose`) conditions, localises, then attributes."""
    say = progress or (lambda msg: None)
    cond_tr, keep_tr, sess_tr = data.train_cs, data.keep_train, data.session_train
    if data.holdout:
        cond_h, keep_h, sess_h, held_s = data.holdout_cs, data.keep_holdout, data.session_holdout, data.holdout_s
        block_s = float(np.clip(2.0 * _correlation_time(model, cond_h, keep_h, sess_h), MIN_BLOCK_S,
                                min(MAX_BLOCK_S, held_s / MIN_BLOCKS)))
        train = GapData.build(model, cond_tr, keep_tr, "training", session_s=sess_tr)
        hold = GapData.build(model, cond_h, keep_h, "holdout", session_s=sess_h)
        say("time dependence")
        tv = time_variation(model, train, hold, alpha)
        att = _select(model, train, hold, _time_blocks(hold, block_s), block_s, (data.train_s, held_s), candidates,
                      alpha, min_gain, max_steps, say, tv, plugins)
        att.encoder = encoder_floor(model, cond_tr + cond_h)
        return att
    total_s = data.train_s
    block_s = float(np.clip(2.0 * _correlation_time(model, cond_tr, keep_tr, sess_tr), MIN_BLOCK_S,
                            min(MAX_BLOCK_S, total_s / (2 * MIN_BLOCKS))))
    halves: tuple[list, list] = ([], [])          # (conditioned piece, keep, source index) per half
    n_blocks = 0
    for g, (cs, kp) in enumerate(zip(cond_tr, keep_tr)):
        idx = np.flatnonzero(kp)
        label = np.floor((cs.t[idx] - cs.t[idx[0]]) / block_s).astype(int)
        for b in np.unique(label):
            sel = idx[label == b]
            if len(sel) < 10:
                continue
            i0, i1 = int(sel[0]), int(sel[-1]) + 1
            halves[n_blocks % 2].append((cs.slice(i0, i1), kp[i0:i1], g))
            n_blocks += 1
    fold_data = []
    for tr, ho in ((halves[0], halves[1]), (halves[1], halves[0])):
        gt = GapData.build(model, [x[0] for x in tr], [x[1] for x in tr], "training", groups=[x[2] for x in tr],
                           session_s=[sess_tr[x[2]] for x in tr])
        gh = GapData.build(model, [x[0] for x in ho], [x[1] for x in ho], "holdout", groups=[x[2] for x in ho],
                           session_s=[sess_tr[x[2]] for x in ho])
        fold_data.append((gt, gh))
    say("time dependence")
    tv = time_variation(model, *fold_data[0], alpha)     # both folds together are all the data
    results = []
    for k, (gt, gh) in enumerate(fold_data):
        say(f"fold {k + 1}/2")
        secs = (sum(len(i) for i in gt.fit_index) / cond_tr[0].rate_hz, sum(len(i) for i in gh.fit_index)
                / cond_tr[0].rate_hz)
        results.append(_select(model, gt, gh, _time_blocks(gh, block_s), block_s, secs,
                               candidates, alpha, min_gain, max_steps, say, tv, plugins))
    tops = [[s.name for s in a.physical_steps] for a in results]
    both = set(tops[0]) | set(tops[1])
    agreement = len(set(tops[0]) & set(tops[1])) / len(both) if both else 1.0
    att = results[0]
    att.cv = CrossValidation(block_s, n_blocks, tops, agreement)
    att.encoder = encoder_floor(model, cond_tr)
    return att


def _params(selected: list[Candidate], fit: Fit, train: GapData, w: np.ndarray
            ) -> dict[str, tuple[np.ndarray, np.ndarray, list[str]]]:
    """The fitted parameters of ``selected`` with their 95 % CI half-widths (module docstring: Jacobian covariance
    inflated by the effective sample size of the training residual)."""
    r_tr = train.residual - predict_candidates(selected, fit, train)
    infl = n_eff_factor(r_tr)
    s2 = float(((r_tr ** 2) * w).sum()) / max(r_tr.size - sum(s.n_params for s in selected), 1)
    return {s.name: (fit.thetas[s.name], 1.96 * np.sqrt(np.maximum(np.diag(fit.cov[s.name]), 0) * s2 * infl),
                     s.param_names()) for s in selected}


def _drop_stand_ins(selected: list[Candidate], steps: list[Step], fit: Fit, train: GapData, hold: GapData,
                    w: np.ndarray, blk: np.ndarray, min_gain: float,
                    with_nuisance: Callable[[list[Candidate]], list[Candidate]], say: Callable[[str], None]
                    ) -> tuple[list[Candidate], list[Step], Fit, list[Superseded]]:
    """The backward check (module docstring, "Stand-ins"): each named physical effect's held-out gain when added last
    to all the other selected ones (refitted without it on the training data); the lowest below ``min_gain`` is
    dropped, the rest refitted, and again — at most :data:`MAX_SUPERSEDED` times. Returns the kept candidates, their
    steps, their fit and what was dropped."""
    e_h, n_blk = hold.residual, int(blk.max()) + 1
    order = [st.name for st in steps]
    dropped: list[Superseded] = []
    for _ in range(MAX_SUPERSEDED):
        physical = {st.name for st in steps if not st.processing}
        pred_all = predict_candidates(selected, fit, hold)
        worst = None
        for c in selected:
            others = [x for x in selected if x is not c]
            if c.name not in physical or not others:
                continue
            f_o = fit_candidates(with_nuisance(others), train, w, fit.thetas,
                                 sweeps=3 if any(not x.linear for x in others) else 1)
            base = predict_candidates(others, f_o, hold)
            g = block_gain(e_h - base, pred_all - base, w, blk, n_blk)[1]
            if g < min_gain and (worst is None or g < worst[1]):
                worst = (c, g, f_o)
        if worst is None:
            break
        c, g, fit = worst
        k = next(i for i, st in enumerate(steps) if st.name == c.name)
        selected = [x for x in selected if x is not c]
        kept = [st.name for st in steps if st.name != c.name and not st.processing]
        dropped.append(Superseded(c.name, order.index(c.name) + 1, float(g), kept))
        steps = steps[:k] + steps[k + 1:]
        say(f"backward check: {c.name} adds {100 * g:.1f} % held-out gain with the others named — a stand-in, "
            "dropped")
    return selected, steps, fit, dropped


def _configuration_joints(r_tr: np.ndarray, train: GapData, alpha: float) -> np.ndarray:
    """The joints (0-based) on which the configuration columns ``q, sin q, cos q`` of the joint's own angle explain
    a significant part of the training residual ``r_tr [M, n]`` beyond a constant: per joint the F test of the
    least-squares fit, its sample count deflated to the effective one of the residual's autocorrelation
    (:func:`~proprio.diagnosis.selection.block_test.n_eff_factor`), at ``alpha``."""
    cols = own_angle_columns(train)
    per = cols.shape[2]
    keep = []
    for j in range(r_tr.shape[1]):
        a, y = cols[:, j], r_tr[:, j]
        y0 = y - y.mean()
        sse0 = float(y0 @ y0)
        if sse0 <= 0:
            continue
        fitted = a @ np.linalg.lstsq(a, y, rcond=None)[0]
        explained = 1.0 - float(((y - fitted) ** 2).sum()) / sse0
        n_eff = len(y) / n_eff_factor(y0[:, None])
        dof = n_eff - per
        if dof <= 0 or explained <= 0:
            continue
        f = (explained / (per - 1)) / max(1.0 - explained, 1e-12) * dof
        if stats.f.sf(f, per - 1, dof) < alpha:
            keep.append(j)
    return np.asarray(keep, dtype=int)


def _beyond_configuration(c: Candidate, selected: list[Candidate], fit_init: dict[str, np.ndarray], train: GapData,
                          hold: GapData, w: np.ndarray, blk: np.ndarray,
                          with_nuisance: Callable[[list[Candidate]], list[Candidate]], pred_h: np.ndarray,
                          joints: np.ndarray) -> tuple[float, float, float]:
    """``(held-out gain of the configuration-only nuisance on ``joints`` added to selected, gain and block t statistic
    of the candidate c added beyond it)`` (module docstring, "Position is not history"); ``pred_h``: the selected
    candidates' held-out prediction."""
    if not len(joints):
        return 0.0, 0.0, 0.0
    cfg = ConfigurationCandidate(train.signals[0].n, joints)
    n_blk = int(blk.max()) + 1
    sweeps = 2 if any(not x.linear for x in selected + [c]) else 1
    f0 = fit_candidates(with_nuisance(selected + [cfg]), train, w, fit_init, sweeps=sweeps)
    p0 = predict_candidates(selected + [cfg], f0, hold)
    g_cfg = block_gain(hold.residual - pred_h, p0 - pred_h, w, blk, n_blk)[1]
    f1 = fit_candidates(with_nuisance(selected + [cfg, c]), train, w, {**fit_init, **f0.thetas}, sweeps=sweeps)
    p1 = predict_candidates(selected + [cfg, c], f1, hold)
    db, g = block_gain(hold.residual - p0, p1 - p0, w, blk, n_blk)
    return float(g_cfg), float(g), float(t_stat(db))


def _select(model: SimModel, train: GapData, hold: GapData, blk: np.ndarray, block_s: float,
            data_seconds: tuple[float, float], candidates: Sequence[str] | None, alpha: float, min_gain: float,
            max_steps: int, say: Callable[[str], None], tv: TimeVariation,
            plugins: Sequence[str | type] = ()) -> Attribution:
    """The greedy forward selection on prepared training / held-out data with held-out block labels ``blk``, then
    the backward check for stand-ins (module docstring, :func:`_drop_stand_ins`); ``tv``: the time-dependence test
    of the same data (when detected: time-varying candidates offered, static ones fitted with the time-trend
    nuisance)."""
    cands = candidate_set(model, train, candidates, plugins, time_varying=tv.detected)
    nuisance = [TimeTrendNuisance(train)] if tv.detected else []

    def with_nuisance(cs: list[Candidate]) -> list[Candidate]:
        """``cs`` plus the time-trend nuisance while none of them is time-varying (module docstring)."""
        return cs + nuisance if not any(c.time_varying for c in cs) else cs

    e_tr, e_h = train.residual, hold.residual
    w = 1.0 / np.maximum((e_tr ** 2).mean(axis=0), 1e-12)
    n_blk = int(blk.max()) + 1
    sig = np.sqrt((hold.stack(hold.tau) ** 2).mean(axis=0))
    rmse0 = np.sqrt((e_h ** 2).mean(axis=0))
    proc_sigma = processing_torque_sigma(model.smooth_torque, hold.conditioned)

    selected: list[Candidate] = []
    fit = Fit({}, {})
    pred_h = np.zeros_like(e_h)
    steps: list[Step] = []
    ranking: list[dict[str, Any]] = []
    below_floor: list[tuple[str, float, float]] = []
    position_only: list[PositionOnly] = []
    undecided: Undecided | None = None
    remaining = list(cands)
    first = True
    while remaining and len(steps) < max_steps:
        r_s = e_h - pred_h
        scored = []
        for c in remaining:
            say(f"step {len(steps) + 1}: fitting {c.name}")
            f_c = fit_candidates(with_nuisance(selected + [c]), train, w, fit.thetas, sweeps=1 if c.linear else 2)
            delta = predict_candidates(selected + [c], f_c, hold) - pred_h
            db, g = block_gain(r_s, delta, w, blk, n_blk)
            raw = float((r_s ** 2).sum() - ((r_s - delta) ** 2).sum())    # unweighted held-out SSE change
            scored.append((c, f_c, db, g if raw > 0 else min(g, 0.0), t_stat(db), delta))
        k_test = len(scored)
        t_crit = stats.t.ppf(1 - alpha / k_test, n_blk - 1)
        if first:
            first = False
            ranking = [{"name": c.name, "gain": max(g, 0.0), "t": t, "n_params": c.n_params,
                        "processing": c.processing, "significant": bool(g >= min_gain and t >= t_crit)}
                       for c, _, _, g, t, _ in scored]
            ranking.sort(key=lambda x: -x["gain"])
        sig_ok = [x for x in scored if x[3] >= min_gain and x[4] >= t_crit]
        if not sig_ok:
            lead = [x for x in scored if not x[0].processing and x[3] >= min_gain and x[4] > 0]
            if lead:
                best = max(lead, key=lambda x: x[3])
                undecided = Undecided(best[0].name, best[3], best[4], float(t_crit), n_blk, block_s)
            break
        sig_ok.sort(key=lambda x: -x[3])
        best = sig_ok[0]
        t_tie = stats.t.ppf(0.95, n_blk - 1)
        group = [best] + [x for x in sig_ok[1:] if t_stat(best[2] - x[2]) < t_tie]
        group.sort(key=lambda x: (x[0].n_params, -x[3]))
        chosen = group[0]
        c, f_c = chosen[0], chosen[1]
        rms_delta = np.sqrt((chosen[5] ** 2).mean(axis=0))
        if not c.processing and np.all(rms_delta <= proc_sigma):     # not named, and not data path either
            below_floor.append((c.name, chosen[3], float(rms_delta.max())))
            remaining = [x for x in remaining if x is not c]
            continue
        if c.name in POSITION_MIMICS:        # position is not history (module docstring)
            say(f"step {len(steps) + 1}: {c.name} beyond the configuration")
            joints = _configuration_joints(e_tr - predict_candidates(selected, fit, train), train, alpha)
            g_cfg, g_beyond, t_beyond = _beyond_configuration(c, selected, {**fit.thetas, **f_c.thetas}, train, hold,
                                                              w, blk, with_nuisance, pred_h, joints)
            if g_cfg >= chosen[3] and (g_beyond < min_gain or t_beyond < t_crit):
                position_only.append(PositionOnly(c.name, float(chosen[3]), g_beyond, t_beyond, g_cfg))
                remaining = [x for x in remaining if x is not c]
                continue
        processing = c.processing
        reason = "describes the data path (filtering, derivative noise)" if processing else ""
        selected.append(c)
        remaining = [x for x in remaining if x is not c]     # tied partners stay: they may still add later
        fit = fit_candidates(with_nuisance(selected), train, w, f_c.thetas, sweeps=3) \
            if any(not s.linear for s in selected) else f_c
        pred_h = predict_candidates(selected, fit, hold)
        steps.append(Step(c.name, [g[0].name for g in group[1:]], chosen[3], chosen[4],
                          np.sqrt(((e_h - pred_h) ** 2).mean(axis=0)), _params(selected, fit, train, w), processing,
                          reason))
        say(f"step {len(steps)}: added {c.name} (held-out gain {100 * chosen[3]:.1f} %)")

    superseded: list[Superseded] = []
    if len(selected) > 1:
        selected, steps, fit, superseded = _drop_stand_ins(selected, steps, fit, train, hold, w, blk, min_gain,
                                                           with_nuisance, say)
        pred_h = predict_candidates(selected, fit, hold)
        if superseded:                  # the last step holds the final fit
            steps[-1].rmse_after = np.sqrt(((e_h - pred_h) ** 2).mean(axis=0))
            steps[-1].params = _params(selected, fit, train, w)
    # the data path never makes the "before" gap: data-path steps the selection took before any physical one are the
    # correction of the data, listed apart (Attribution.data_path); the gap before is reported after them
    lead = next((i for i, st in enumerate(steps) if not st.processing), len(steps))
    data_path, steps = steps[:lead], steps[lead:]
    rmse_raw = None
    if data_path:
        rmse_raw, rmse0 = rmse0, data_path[-1].rmse_after
    r_h = e_h - pred_h
    r_tr = e_tr - predict_candidates(selected, fit, train)
    rate = float(np.median([cs.rate_hz for cs in hold.conditioned]))
    structure = residual_structure(r_h, r_tr, train, hold, rate, proc_sigma)
    noise = noise_findings(model, structure, hold, r_h)
    say("hints on the remaining residual")
    structured = np.flatnonzero(structure.structured_time | structure.structured_state
                                | (shifted_joints(r_h, blk, alpha) & ~structure.within_processing))
    parts = [np.stack([predict_candidates([c], fit, d) for c in selected], axis=2) if selected and len(structured)
             else None for d in (train, hold)]
    hints = find_hints(train, hold, r_tr, r_h, structured, blk, parts[0], parts[1], alpha=alpha)
    amb = ambiguity_sets(selected, [not st.processing for st in data_path + steps], cands, ranking, train, hold, w, blk,
                         with_nuisance, structure.rmse, min_gain, say)
    return Attribution(model.robot.joint_names, steps, ranking, rmse0, sig, structure, noise,
                       [c.name for c in cands], split_by_recording(e_h, hold), split_by_recording(pred_h, hold),
                       hold.times, proc_sigma, sorted({cs.describe() for cs in hold.conditioned + train.conditioned}),
                       data_seconds, block_s, fitted={c.name: c for c in selected}, hints=hints, time_variation=tv,
                       undecided=undecided, below_floor=below_floor, ambiguity=amb, superseded=superseded,
                       position_only=position_only, data_path=data_path, rmse_raw=rmse_raw,
                       missing_term=missing_model_term(model, train, hold))
