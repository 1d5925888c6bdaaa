"""Which other candidates could take a named effect's place on these data (issue #25, "ambiguity, measured and
said").

Several effects flip with the direction of motion (Coulomb friction, torque-sensor hysteresis, lost motion) or
scale with the load (a sensor gain error, a rigid-body error, a payload); on the motions of one recording they can
explain the same residual. For every physical effect ``s`` the selection named, with ``C`` the other selected
effects (its *context*, fitted alongside every time):

* ``g(x)``: the relative held-out gain of ``C + x`` over ``C`` (the weighted block SSE of
  :func:`proprio.diagnosis.selection.block_test.block_gain`), for ``x = s`` and for every *alternative* — any other
  physical candidate whose step-1 gain alone is within a factor :data:`ALT_MIN_SHARE` of ``s``'s either way (at most
  :data:`MAX_ALTERNATIVES`, the strongest first; none when ``s`` itself gains less than ``min_gain`` in its
  place); an alternative the selection also named leaves the context ``C`` for the comparison (both were named:
  can one do the other's work?);
* ``share = g(alt) / g(s)``: how much of ``s``'s held-out gain the alternative explains when swapped in;
* ``correlation``: the weighted correlation of the two held-out torque predictions (``C + x`` minus ``C``);
* ``t``: the paired one-sided block t-test of ``s`` against the alternative (log-ratio differences, as the
  selection's tie test);
* ``pair_shared``: the share of the pair's joint gain ``g(s + alt)`` that either explains alone,
  ``(g(s) + g(alt) − g(s + alt)) / g(s + alt)`` (the shared share below, for the pair).

The alternative is **tied** with ``s`` — it can take ``s``'s place — only when all of these hold:

1. it explains at least :data:`TIE_SHARE` (half) of ``s``'s held-out gain in its place: less, and what it leaves
   unexplained is the larger part;
2. ``s`` is not significantly better (the selection's own tie test, one-sided 5 %);
3. their held-out torques are alike: correlation at least :data:`TIE_CORRELATION` = 1/√2, i.e. more than half of
   either prediction's (weighted) variance lies along the other's (R² > ½);
4. what they explain is mostly the same: ``pair_shared`` at least :data:`TIE_SHARED` (half), i.e. the shared part
   outweighs the exclusive parts together. Two effects that each explain a different part of the residual by a
   similar amount (a rigid-body error and friction on a real arm) pass 1 and 2 but are not a tie: both are needed.

Each threshold is the "more than half" of its quantity, not a value fitted to data; 1 and 2 alone (the rule before)
said "tie" for two effects of similar strength whatever they explain.

A tied set ``S`` (``s`` and its tied alternatives) is fitted jointly over the selected effects outside it,
``g(S)``; the **exclusive** share of a member ``x`` is ``(g(S) − g(S∖x)) / g(S)`` (what only it explains), the
**shared** share ``1 − Σ exclusive`` (what any of them explains). The fits of every member in ``s``'s place are
kept (:attr:`AmbiguitySet.fits`): the designed experiment (:mod:`proprio.diagnosis.discriminate`) predicts each
hypothesis on a new motion with them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from scipy import stats

from proprio.diagnosis.selection.block_test import block_gain, t_stat
from proprio.diagnosis.candidates.base import Candidate
from proprio.diagnosis.data import GapData
from proprio.diagnosis.fitting import Fit, fit_candidates, predict_candidates

__all__ = ["Alternative", "AmbiguitySet", "ambiguity_sets", "ambiguity_markdown", "tied_sets", "is_tie",
           "ALT_MIN_SHARE", "TIE_SHARE", "TIE_CORRELATION", "TIE_SHARED", "MAX_ALTERNATIVES"]

ALT_MIN_SHARE = 0.3      # an alternative is tested when its step-1 gain alone is 30–333 % of the effect's
TIE_SHARE = 0.5          # ... tied only if it explains ≥ half of the effect's gain in its place,
TIE_CORRELATION = 1.0 / math.sqrt(2.0)   # its held-out torque shares > half its variance with the effect's (R² > ½)
TIE_SHARED = 0.5         # ... and > half of the pair's joint gain is shared (module docstring: the tie rule)
MAX_ALTERNATIVES = 3


@dataclass
class Alternative:
    """A candidate swapped in for a named effect: its held-out gain in the effect's place as a share of the
    effect's own (``share``), the correlation of the two held-out torque predictions, the paired block t statistic
    of the effect against it (large: the effect is significantly better), the shared share of the pair's joint gain
    (``pair_shared``; NaN when not needed: a criterion before it failed) and whether they are tied."""
    name: str
    gain: float
    share: float
    correlation: float
    t_stat: float
    tied: bool
    pair_shared: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "gain": self.gain, "share": self.share, "correlation": self.correlation,
                "t": self.t_stat, "pair_shared": None if math.isnan(self.pair_shared) else self.pair_shared,
                "tied": self.tied}


@dataclass
class AmbiguitySet:
    """The named ``effect`` with its held-out ``gain`` in its place, the alternatives tested, and the tied set
    (``members``: the effect first) with its joint gain, shared share and exclusive share per member (fractions of
    ``joint_gain``). ``fits``: each member fitted in the effect's place with the ``context`` (the other selected
    effects); ``candidates``: the member and context candidates by name; ``weights [n]``: the joint weights of the
    fits; ``sigma [n]`` N·m: the held-out residual RMS after every selected effect (the noise an experiment must
    beat); ``home [n]`` rad: a training configuration near the median of the motion (the experiment's start)."""
    effect: str
    gain: float
    alternatives: list[Alternative]
    members: list[str]
    joint_gain: float
    shared: float
    exclusive: dict[str, float]
    context: list[str]
    fits: dict[str, Fit] = field(default_factory=dict, repr=False)
    candidates: dict[str, Candidate] = field(default_factory=dict, repr=False)
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    sigma: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    home: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    @property
    def tied(self) -> bool:
        return len(self.members) > 1

    def text(self, plain: dict[str, str] | None = None) -> str:
        """One sentence: the tied set with its shared and exclusive shares, or the closest alternative."""
        nm = (lambda k: (plain or {}).get(k, k))
        if self.tied:
            excl = ", ".join(f"{nm(k)} {100 * v:.0f} %" for k, v in self.exclusive.items())
            return (f"On these data {' and '.join(nm(k) for k in self.members)} can take each other's place: "
                    f"{100 * self.shared:.0f} % of what they explain together is shared (exclusive: {excl}); "
                    f"the correlation of their held-out torques is "
                    f"{', '.join(f'{a.correlation:.2f}' for a in self.alternatives if a.tied)} — a tie, not a "
                    "ranking (an experiment that separates them: diagnose --design-experiment / --resolve).")
        if self.alternatives:
            a = max(self.alternatives, key=lambda x: x.share)
            return (f"No other candidate takes the place of {nm(self.effect)}: the closest, {nm(a.name)}, explains "
                    f"{100 * a.share:.0f} % of its held-out gain in its place, their held-out torques correlate "
                    f"{a.correlation:.2f} (block t = {a.t_stat:.1f} for {nm(self.effect)}).")
        if self.gain < 0.02:
            return f"{nm(self.effect)} adds little once the other named effects are in: no alternative tested."
        return f"No other candidate takes the place of {nm(self.effect)} on these data."

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "gain": self.gain, "members": self.members, "tied": self.tied,
                "joint_gain": self.joint_gain, "shared": self.shared, "exclusive": self.exclusive,
                "context": self.context, "alternatives": [a.to_dict() for a in self.alternatives]}


def _corr(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> float:
    sw = np.sqrt(w)[None, :]
    a, b = (a * sw).ravel(), (b * sw).ravel()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / den if den > 0 else 0.0


def is_tie(gain: float, share: float, t_stat: float, t_crit: float, correlation: float, pair_shared: float,
           min_gain: float) -> bool:
    """The tie rule of the module docstring: the alternative gains at least ``min_gain`` in the effect's place,
    explains ≥ :data:`TIE_SHARE` of the effect's gain (``share``), the effect is not significantly better
    (``t_stat < t_crit``), their held-out torques correlate ≥ :data:`TIE_CORRELATION` and ≥ :data:`TIE_SHARED` of
    the pair's joint gain is shared (``pair_shared``)."""
    return bool(gain >= min_gain and share >= TIE_SHARE and t_stat < t_crit and correlation >= TIE_CORRELATION
                and pair_shared >= TIE_SHARED)


def _home(train: GapData) -> np.ndarray:
    """The training configuration nearest the per-joint median of the training motion [rad]."""
    q = train.stack([s.q for s in train.signals])
    med = np.median(q, axis=0)
    return q[int(np.argmin(((q - med) ** 2).sum(axis=1)))].copy()


def ambiguity_sets(selected: Sequence[Candidate], physical: Sequence[bool], cands: Sequence[Candidate],
                   ranking: Sequence[dict[str, Any]], train: GapData, hold: GapData, w: np.ndarray, blk: np.ndarray,
                   with_nuisance: Callable[[list[Candidate]], list[Candidate]], sigma: np.ndarray,
                   min_gain: float = 0.02, say: Callable[[str], None] = lambda m: None) -> list[AmbiguitySet]:
    """One :class:`AmbiguitySet` per selected physical effect (``physical[i]`` for ``selected[i]``), measured on the
    training (fits) and held-out (gains, correlations) data of the selection (module docstring). ``ranking``: the
    step-1 ranking of the selection (gain of each candidate alone); ``with_nuisance``: adds the time-trend nuisance
    where the selection fits one; ``sigma [n]`` N·m: the held-out RMS left after the selection."""
    e_h = hold.residual
    n_blk = int(blk.max()) + 1
    alone = {r["name"]: float(r["gain"]) for r in ranking}
    by_name = {c.name: c for c in cands}
    home = _home(train)
    t_tie = stats.t.ppf(0.95, n_blk - 1)
    memo: dict[frozenset, tuple[Fit, np.ndarray]] = {}

    def fit_pred(cs: list[Candidate]) -> tuple[Fit, np.ndarray]:
        key = frozenset(c.name for c in cs)
        if key not in memo:
            f = fit_candidates(with_nuisance(cs), train, w, {}, sweeps=3 if any(not c.linear for c in cs) else 1) \
                if cs else Fit({}, {})
            memo[key] = (f, predict_candidates(cs, f, hold) if cs else np.zeros_like(e_h))
        return memo[key]

    def gain(ctx: list[Candidate], extra: list[Candidate]) -> tuple[np.ndarray, float, np.ndarray]:
        """Block log-ratios, relative held-out gain and held-out torque of ``ctx + extra`` over ``ctx``."""
        base = fit_pred(ctx)[1]
        delta = fit_pred(ctx + extra)[1] - base
        lb, g = block_gain(e_h - base, delta, w, blk, n_blk)
        return lb, g, delta

    out = []
    for s, phys in zip(selected, physical):
        if not phys:
            continue
        say(f"ambiguity: {s.name}")
        context = [c for c in selected if c is not s]
        g_s = gain(context, [s])[1]
        a_s = alone.get(s.name, g_s)
        pool = [] if g_s < min_gain else sorted(
            (c for c in cands if c is not s and not c.processing
             and max(min_gain, ALT_MIN_SHARE * a_s) <= alone.get(c.name, 0.0) <= a_s / ALT_MIN_SHARE),
            key=lambda c: -alone.get(c.name, 0.0))[:MAX_ALTERNATIVES]
        alts = []
        for c in pool:
            ctx = [x for x in context if x is not c]        # a selected alternative leaves the context
            lb_s, gs, d_s = gain(ctx, [s])
            lb_c, gc, d_c = gain(ctx, [c])
            share = gc / gs if gs > 0 else 0.0
            t = t_stat(lb_s - lb_c)
            rho = _corr(d_s, d_c, w)
            pair = math.nan
            if is_tie(gc, share, t, t_tie, rho, 1.0, min_gain):       # only then is the joint fit needed
                g_sc = gain(ctx, [s, c])[1]
                pair = float((gs + gc - g_sc) / g_sc) if g_sc > 0 else 0.0
            alts.append(Alternative(c.name, gc, share, rho, t, is_tie(gc, share, t, t_tie, rho, pair, min_gain),
                                    pair))
        members = [s.name] + [a.name for a in alts if a.tied]
        mem = [s] + [by_name[k] for k in members[1:]]
        ctx = [x for x in selected if x.name not in members]
        joint, shared, excl = g_s, 1.0, {s.name: 1.0}
        if len(mem) > 1:
            joint = gain(ctx, mem)[1]
            excl = {x.name: float(max(joint - gain(ctx, [m for m in mem if m is not x])[1], 0.0) / joint)
                    if joint > 0 else 0.0 for x in mem}
            shared = float(max(1.0 - sum(excl.values()), 0.0))
        out.append(AmbiguitySet(s.name, g_s, alts, members, float(joint), shared, excl, [c.name for c in ctx],
                                fits={x.name: fit_pred(ctx + [x])[0] for x in mem},
                                candidates={**{c.name: c for c in ctx}, **{x.name: x for x in mem}},
                                weights=w, sigma=np.asarray(sigma, dtype=float), home=home))
    return out


def tied_sets(sets: Sequence[AmbiguitySet]) -> list[AmbiguitySet]:
    """The tied sets of ``sets``, each set of members once (two named effects tied with each other give one)."""
    seen: set[frozenset] = set()
    out = []
    for a in sets:
        key = frozenset(a.members)
        if a.tied and key not in seen:
            seen.add(key)
            out.append(a)
    return out


def ambiguity_markdown(sets: Sequence[AmbiguitySet]) -> str:
    """The report's ambiguity section: per named effect the alternatives swapped into its place, then the tied
    sets with their shared and exclusive shares."""
    if not sets:
        return "No physical effect was named: nothing to compare."
    rows = ["| named effect | its held-out gain [%] | alternative | gain in its place [%] | share of the effect's "
            "gain [%] | correlation of the held-out torques | block t (effect better) | shared of the pair's gain "
            "[%] | tied |",
            "|---|---|---|---|---|---|---|---|---|"]
    for a in sets:
        if not a.alternatives:
            rows.append(f"| {a.effect} | {100 * a.gain:.1f} | — | — | — | — | — | — | — |")
        for x in a.alternatives:
            pair = "—" if math.isnan(x.pair_shared) else f"{100 * x.pair_shared:.0f}"
            rows.append(f"| {a.effect} | {100 * a.gain:.1f} | {x.name} | {100 * x.gain:.1f} | {100 * x.share:.0f} | "
                        f"{x.correlation:.2f} | {x.t_stat:.1f} | {pair} | {'yes' if x.tied else 'no'} |")
    head = ("Each alternative is fitted in the named effect's place (with the other named effects) on the training "
            "data and scored on the held-out data; tied: it explains at least half of the effect's gain, the "
            "block test cannot tell them apart, their held-out torques correlate ≥ 0.71 (R² > ½) and more than half "
            "of what the two explain together is shared.")
    tied = [a.text() for a in tied_sets(sets)] or [
        "No tie: no alternative can take a named effect's place (the rule above)."]
    return "\n\n".join([head, "\n".join(rows)] + tied)
