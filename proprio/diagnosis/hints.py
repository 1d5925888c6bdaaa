"""Hints beyond the library: when a structured residual remains after the greedy attribution
(:mod:`~proprio.diagnosis.selection.forward`) — autocorrelated or state-dependent, or off zero on average on the
held-out data (:func:`shifted_joints`) — a sparse regression per such joint over a broad dictionary of measured
and modelled signals says *what* the remaining residual follows — labelled as a hint with its held-out gain, never
as a library effect.

**Dictionary** (per sample; joint ``k`` = 1..n, ids as in :attr:`Hint.signals`):

* ``τ_k`` — the *modelled* link-side torque of every joint (:attr:`GapData.signals` ``.tau``). The measured τ of the
  joint under test is never a feature: its residual is ``τ_meas − τ_sim``, so regressing it on its own ``τ_meas``
  would explain the residual by itself (circular). The modelled τ carries the same load information without the
  measurement's own error, so it is used for every joint, including the one under test (a gain error);
* ``q_k``, ``q̇_k``, ``q̈_k`` (conditioned), ``tanh(q̇_k / v₀)`` (the smooth sign of
  :mod:`proprio.friction_law`, ``v₀`` its library default), ``|q̇_k| q̇_k``;
* ``sin(m q_k)``, ``cos(m q_k)``, ``m`` = 1..3 (position-dependent terms, e.g. an unmodelled ripple or cogging);
* products ``q̇_k |τ_k|`` and ``tanh(q̇_k / v₀) |τ_k|`` (load-dependent viscous / Coulomb friction);
* ``time`` — the session clock ``t + meta["session_time_s"]`` [s] (:class:`~proprio.diagnosis.data.GapData`; the
  recording's own time where it has no session time): a drift.

**Fit.** Features are standardised on the training samples (the training set is already strided down to
``MAX_FIT_SAMPLES``, :class:`~proprio.diagnosis.data.GapData`). A candidate fitted to a residual that also holds an
effect outside the library absorbs part of it (a hysteresis loop fitted to a cross-talk, say), so each selected
candidate's fitted torque on the joint is an unpenalised column of the hint's fit, projected out of the residual and of
the dictionary first (Frisch–Waugh) and re-scaled jointly with the hint — never a hint term. Orthogonal matching
pursuit (scikit-learn's ``orthogonal_mp_gram`` on the re-standardised projected dictionary) then fits the *training*
residual with 1..``MAX_TERMS`` terms; the number of terms is chosen by time-blocked cross-validation (``GroupKFold``
over contiguous time blocks, never random samples: the residual is autocorrelated) as the fewest whose
cross-validated gain is within 5 % of the best, and those terms are refitted by least squares with the candidates'
columns. Training data only: the held-out data score it.

**Score.** On the held-out residual of that joint, the hint's relative gain ``G = 1 − SSE(r − ĥ) / SSE(r − b̂)``
against ``b̂``, the re-scaled candidates alone (with a constant: a constant or a re-scaling alone earns no hint); it is
reported when ``G ≥ min_gain`` (5 %) and a one-sided t-test over the held-out time blocks of the selection (log-ratio
of the block SSEs, as the selection's test) rejects "no gain" at ``α / K`` (Bonferroni over the ``K`` joints tested).

**Well-posed coefficients.** A dictionary column that is almost one of the candidates' fitted torques on the joint
(a velocity where viscous friction was fitted) keeps only a sliver after the projection; re-standardised, that
sliver looks like any other column, and the joint fit then gives the term a huge coefficient that the candidate's
re-scaling cancels (a velocity coefficient of −2.25 N·m·s/rad on a joint whose whole residual is 0.23 N·m RMS). So a
column whose variance inflation factor against the candidates' columns exceeds :data:`MAX_VIF` (the usual bound of
serious multicollinearity) is not offered, and a hint one of whose terms alone moves the joint's torque by more
than the whole residual it explains (the terms cancel each other) is not reported.

**Resemblance.** A term on the joint's own signals that is the law of a library candidate (its velocity: viscous
friction; the smooth sign of its velocity: Coulomb friction; its acceleration: rotor inertia or a rigid-body error;
its own modelled τ: a gain error; ``sin/cos(q)`` of any joint: a rigid-body (gravity) error; the time: a drifting
offset) is
named in :attr:`Hint.resembles`, so that the report says which library effect the hint resembles and why that effect
was not taken.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import stats
from sklearn.linear_model import orthogonal_mp_gram
from sklearn.model_selection import GroupKFold

from proprio import friction_law
from proprio.diagnosis.data import GapData

__all__ = ["Hint", "Term", "dictionary", "find_hints", "shifted_joints", "MAX_TERMS", "HINT_MIN_GAIN", "MAX_VIF"]

MAX_TERMS = 3
HINT_MIN_GAIN = 0.05
CV_FOLDS = 5
CV_BLOCKS = 40                # contiguous training time blocks the folds are drawn from
HARMONICS = (1, 2, 3)
MAX_VIF = 10.0                # variance inflation beyond which a column is a re-scaled candidate (module docstring)
_SUB = str.maketrans("0123456789", "₀₁₂₃₄₅₆₇₈₉")


def _sub(k: int) -> str:
    return str(k).translate(_SUB)


@dataclass
class Hint:
    """What the remaining residual of one joint follows (a hint, never a library effect).

    ``joint`` (0-based), ``terms`` (the dictionary terms, most important first, e.g. ``"τ₂"``, ``"sin(2q₃)"``),
    ``signals`` (their base signal ids, most important first: ``"tau_2"``, ``"q_3"``, ``"qd_1"``, ``"qdd_4"``,
    ``"time"``, joints 1-based), ``gain`` (held-out relative SSE reduction on that joint), ``text`` (plain words),
    ``coefficients`` (of the terms, in their SI units: N·m per unit of the term), ``units`` (of the coefficients),
    ``t_stat`` (block t statistic), ``resembles`` (``(term, candidates)`` for each term on the joint's own signals
    that is a library candidate's law, module docstring), ``rms`` [N·m] (the joint's remaining residual it was fitted
    to, training data)."""
    joint: int
    terms: list[str]
    signals: list[str]
    gain: float
    text: str
    coefficients: list[float] = field(default_factory=list)
    t_stat: float = 0.0
    units: list[str] = field(default_factory=list)
    resembles: list[tuple[str, tuple[str, ...]]] = field(default_factory=list)
    rms: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``diagnosis.json`` ``hints``)."""
        return {"joint": self.joint, "terms": self.terms, "signals": self.signals, "gain": self.gain,
                "coefficients": self.coefficients, "units": self.units, "t": self.t_stat, "text": self.text,
                "resembles": [{"term": t, "candidates": list(c)} for t, c in self.resembles], "rms": self.rms}


@dataclass(frozen=True)
class Term:
    """One dictionary column: ``name`` (plain, e.g. ``"q̇₁·|τ₁|"``), ``signals`` (base signal ids), ``phrase`` (what
    "the residual ... " does with it, given its coefficient), ``unit`` of its coefficient, ``joint`` (1-based) whose
    signals it is built from (0: the time), ``library`` (the candidates whose law it is on that joint, module
    docstring)."""
    name: str
    signals: tuple[str, ...]
    phrase: str
    unit: str
    joint: int = 0
    library: tuple[str, ...] = ()


def _terms(n: int) -> list[Term]:
    out = []
    for k in range(1, n + 1):
        s = _sub(k)
        out += [Term(f"τ{s}", (f"tau_{k}",), f"follows τ of joint {k}", "", k, ("sensor_gain", "sensor_offset_gain")),
                Term(f"q{s}", (f"q_{k}",), f"grows with q{s}", "N·m/rad", k),
                Term(f"q̇{s}", (f"qd_{k}",), f"follows the velocity q̇{s}", "N·m·s/rad", k,
                     ("viscous_coulomb", "motor_friction")),
                Term(f"q̈{s}", (f"qdd_{k}",), f"follows the acceleration q̈{s}", "N·m·s²/rad", k,
                     ("rotor_inertia", "rigid_body")),
                Term(f"tanh(q̇{s}/v₀)", (f"qd_{k}",), f"steps with the direction of motion of joint {k}", "N·m", k,
                     ("viscous_coulomb", "motor_friction")),
                Term(f"|q̇{s}|q̇{s}", (f"qd_{k}",), f"grows with the square of q̇{s}", "N·m·s²/rad²", k)]
        for m in HARMONICS:
            mm = "" if m == 1 else str(m)
            lib = ("rigid_body",) if m == 1 else ()
            out += [Term(f"sin({mm}q{s})", (f"q_{k}",), f"varies with sin({mm}q{s}) (periodic in q{s})", "N·m", k, lib),
                    Term(f"cos({mm}q{s})", (f"q_{k}",), f"varies with cos({mm}q{s}) (periodic in q{s})", "N·m", k,
                         lib)]
        out += [Term(f"q̇{s}·|τ{s}|", (f"qd_{k}", f"tau_{k}"), f"follows q̇{s}·|τ{s}| (load-dependent viscous "
                     "friction)", "s/rad", k),
                Term(f"tanh(q̇{s}/v₀)·|τ{s}|", (f"qd_{k}", f"tau_{k}"), f"follows sign(q̇{s})·|τ{s}| (load-dependent "
                     "Coulomb friction)", "", k)]
    out.append(Term("time", ("time",), "drifts with time", "N·m/s", 0, ("offset_drift",)))
    return out


def dictionary(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tau: np.ndarray, t: np.ndarray
               ) -> tuple[np.ndarray, list[Term]]:
    """The hint dictionary (module docstring) of one set of samples: ``q, qd, qdd [N,n]`` (rad, rad/s, rad/s²),
    ``tau [N,n]`` the modelled link-side torque [N·m], ``t [N]`` the (session) time [s]. Returns ``F [N,P]`` and its
    ``P`` terms in column order."""
    n = q.shape[1]
    sgn = friction_law.smooth_sign(qd)
    per = [tau, q, qd, qdd, sgn, np.abs(qd) * qd]
    for m in HARMONICS:
        per += [np.sin(m * q), np.cos(m * q)]
    per += [qd * np.abs(tau), sgn * np.abs(tau)]
    f = np.stack(per, axis=2).reshape(len(q), n * len(per))      # joint-major: joint k's columns together
    return np.concatenate([f, t[:, None]], axis=1), _terms(n)


def _features(data: GapData) -> tuple[np.ndarray, list[Term]]:
    # data.signals are on the session clock (GapData.build), cross-validation pieces included
    cols = [dictionary(s.q[i], s.qd[i], s.qdd[i], s.tau[i], s.t[i])[0] for s, i in zip(data.signals, data.fit_index)]
    return np.concatenate(cols), _terms(data.signals[0].q.shape[1])


def _omp_cv(z: np.ndarray, y: np.ndarray, folds: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Blocked cross-validated relative SSE reduction ``[MAX_TERMS]`` of OMP fits of ``y [N]`` with 1..MAX_TERMS terms
    (with intercept) on the standardised dictionary ``z [N,P]``."""
    sse, sse0 = np.zeros(MAX_TERMS), 0.0
    for tr, te in folds:
        mz, my = z[tr].mean(axis=0), y[tr].mean()
        zc = z[tr] - mz
        path = _path(orthogonal_mp_gram(zc.T @ zc, zc.T @ (y[tr] - my), n_nonzero_coefs=MAX_TERMS,
                                        return_path=True))
        res = (y[te] - my)[:, None] - (z[te] - mz) @ path
        sse += (res ** 2).sum(axis=0)
        sse0 += float(((y[te] - my) ** 2).sum())
    return 1.0 - sse / max(sse0, 1e-300)


def _path(coef: np.ndarray) -> np.ndarray:
    """OMP coefficient path as ``[P, MAX_TERMS]`` (sklearn stops early when the residual vanishes: the last step is
    repeated)."""
    if coef.ndim == 1:
        coef = coef[:, None]
    return np.concatenate([coef] + [coef[:, -1:]] * (MAX_TERMS - coef.shape[1]), axis=1)


def _project_out(x: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``x`` less its least-squares projection on the columns of ``basis`` (Frisch–Waugh: what a joint fit with the
    basis leaves to the other columns)."""
    if basis.shape[1] == 0:
        return x
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    return x - basis @ coef


def _hint_text(j: int, terms: list[Term], coef: np.ndarray, gain: float) -> str:
    bits = []
    for tm, c in zip(terms, coef):
        phrase = tm.phrase
        if phrase.startswith("grows with") and c < 0:
            phrase = "falls with" + phrase[len("grows with"):]
        if tm.name == f"τ{_sub(j + 1)}":
            phrase += " (its own modelled torque: a gain error)"
        bits.append(f"{phrase} (coefficient {c:.3g}{' ' + tm.unit if tm.unit else ''})")
    return (f"Hint: joint {j + 1}'s remaining residual " + "; and ".join(bits)
            + f" — held-out gain {100 * gain:.0f} %.")


def shifted_joints(r_h: np.ndarray, blk: np.ndarray, alpha: float = 0.01) -> np.ndarray:
    """``bool [n]``: joints whose held-out residual ``r_h [N_h,n]`` (N·m) is off zero on average — a level the
    training fit did not see (a drift or a step between recordings), which the whiteness test of the selection
    cannot flag since it removes the mean. Two-sided t-test of the block means ``blk [N_h]`` at ``α / n``."""
    n_blk = int(blk.max()) + 1
    cnt = np.bincount(blk, minlength=n_blk)[:, None]
    means = np.stack([np.bincount(blk, weights=r_h[:, j], minlength=n_blk) for j in range(r_h.shape[1])], axis=1) / cnt
    p = stats.ttest_1samp(means, 0.0, axis=0).pvalue
    return np.nan_to_num(p, nan=1.0) < alpha / r_h.shape[1]


def find_hints(train: GapData, hold: GapData, r_tr: np.ndarray, r_h: np.ndarray, joints: Sequence[int],
               blk: np.ndarray, parts_tr: np.ndarray | None = None, parts_h: np.ndarray | None = None,
               alpha: float = 0.01, min_gain: float = HINT_MIN_GAIN) -> list[Hint]:
    """Hints for the residual left after the selected candidates (module docstring).

    ``r_tr [N_tr,n]`` / ``r_h [N_h,n]`` N·m: the training / held-out residual at the kept samples of ``train`` /
    ``hold``; ``joints``: 0-based joints whose residual is structured (the only ones tested); ``blk [N_h]``: the
    held-out time-block label per sample (the selection's). ``parts_tr [N_tr,n,C]`` / ``parts_h [N_h,n,C]`` N·m: the
    torque of each of the ``C`` selected candidates as fitted (none: ``None``). A candidate fitted to a residual that
    also holds an effect outside the library absorbs part of it, so each candidate's torque on the joint is an
    unpenalised column of the hint's fit (re-scaled jointly, never a hint term), and the gain is measured against
    that re-scaling alone. Returns the significant hints, best gain first."""
    joints = list(joints)
    if not joints:
        return []
    f_tr, terms = _features(train)
    f_h, _ = _features(hold)
    mu, sd = f_tr.mean(axis=0), f_tr.std(axis=0)
    use = sd > 1e-9 * np.maximum(np.abs(mu), 1.0)                  # constant columns carry nothing
    z_tr = (f_tr[:, use] - mu[use]) / sd[use]
    z_h = (f_h[:, use] - mu[use]) / sd[use]
    names = [t for t, u in zip(terms, use) if u]
    groups = train.blocks(CV_BLOCKS)
    folds = list(GroupKFold(n_splits=min(CV_FOLDS, len(np.unique(groups)))).split(z_tr, groups=groups))
    n_blk = int(blk.max()) + 1
    t_crit = stats.t.ppf(1 - alpha / len(joints), n_blk - 1)
    n = r_tr.shape[1]
    if parts_tr is None or parts_h is None:
        parts_tr, parts_h = np.zeros((len(r_tr), n, 0)), np.zeros((len(r_h), n, 0))
    hints = []
    for j in joints:
        live = parts_tr[:, j].std(axis=0) > 1e-9                   # the candidates that act on this joint
        nu_tr = np.column_stack([np.ones(len(r_tr)), parts_tr[:, j, live]])
        nu_h = np.column_stack([np.ones(len(r_h)), parts_h[:, j, live]])
        y = _project_out(r_tr[:, j], nu_tr)
        zj = _project_out(z_tr, nu_tr)
        norm = zj.std(axis=0)                       # z_tr has unit variance: 1/norm² is the column's VIF
        zj = zj / np.where(norm ** 2 > 1.0 / MAX_VIF, norm, np.inf)  # re-standardised: OMP compares correlations
        cv_gain = _omp_cv(zj, y, folds)
        best = float(cv_gain.max())
        if best <= 0:
            continue
        k = int(np.argmax(cv_gain >= 0.95 * best))                   # fewest terms within 5 % of the best
        sel = np.flatnonzero(_path(orthogonal_mp_gram(zj.T @ zj, zj.T @ y, n_nonzero_coefs=k + 1,
                                                      return_path=True))[:, k])
        base_coef, *_ = np.linalg.lstsq(nu_tr, r_tr[:, j], rcond=None)
        coef, *_ = np.linalg.lstsq(np.column_stack([nu_tr, z_tr[:, sel]]), r_tr[:, j], rcond=None)
        base = r_h[:, j] - nu_h @ base_coef
        after = r_h[:, j] - np.column_stack([nu_h, z_h[:, sel]]) @ coef
        b0 = np.bincount(blk, weights=base ** 2, minlength=n_blk)
        b1 = np.bincount(blk, weights=after ** 2, minlength=n_blk)
        gain = 1.0 - float(b1.sum()) / max(float(b0.sum()), 1e-300)
        lb = np.log(np.maximum(b0, 1e-300) / np.maximum(b1, 1e-300))
        sd_lb = float(np.std(lb, ddof=1))
        t_stat = float(lb.mean() / (sd_lb / np.sqrt(n_blk))) if sd_lb > 0 else (np.inf if lb.mean() > 0 else -np.inf)
        if gain < min_gain or t_stat < t_crit:
            continue
        c_z = coef[nu_tr.shape[1]:]
        rms = float(np.std(y))
        if np.max(np.abs(c_z) * norm[sel]) > rms:   # a term's own part alone exceeds the residual: terms cancel
            continue
        order = np.argsort(-np.abs(c_z))                                 # standardised: comparable across terms
        sel_terms = [names[sel[i]] for i in order]
        c_si = c_z[order] / sd[np.flatnonzero(use)[sel[order]]]         # back to the terms' own units
        signals = list(dict.fromkeys(s for tm in sel_terms for s in tm.signals))
        resembles = [(tm.name, tm.library) for tm in sel_terms                 # gravity: any joint's angle
                     if tm.library and (tm.joint in (0, j + 1) or tm.library == ("rigid_body",))]
        hints.append(Hint(int(j), [tm.name for tm in sel_terms], signals, gain, _hint_text(j, sel_terms, c_si, gain),
                          [float(c) for c in c_si], float(t_stat), [tm.unit or "N·m" for tm in sel_terms],
                          resembles, rms))
    hints.sort(key=lambda h: -h.gain)
    return hints
