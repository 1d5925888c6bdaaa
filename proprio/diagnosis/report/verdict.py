"""The plain-language verdict of a diagnosis: where the gap is, which effects explain it, how far it shrinks and
what stays unexplained.

The report opens with :func:`verdict_sentence` (one sentence, ≤ :data:`MAX_VERDICT_CHARS` characters) and the summary
table (:func:`summary_rows`: one :class:`SummaryRow` per named effect, data-path step, undecided leader, noise or
time finding — a new kind of finding is one more row); the explanations (:func:`where_text`, :func:`effects_text`,
:func:`remains_text`, :func:`hint_texts`, :func:`offset_advice`) are the details sections; :func:`verdict_text` is all
of them in one text (``Diagnosis.explanation``)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

from proprio.diagnosis.selection.ambiguity import tied_sets
from proprio.diagnosis.localisation import GapMap
from proprio.diagnosis.attribution import Attribution

__all__ = ["PLAIN", "plain_names", "verdict_text", "undecided_text", "data_and_processing_text", "verdict_sentence",
           "SummaryRow", "summary_rows", "where_text", "effects_text", "remains_text", "hint_texts", "offset_advice",
           "OffsetAdvice", "MAX_VERDICT_CHARS", "Verdict", "make_verdict"]

MAX_VERDICT_CHARS = 800
"""The verdict sentence's length bound (read in a minute: the explanations are the report's details)."""

PLAIN = {"viscous_coulomb": "viscous + Coulomb friction", "stribeck": "Stribeck (static) friction",
         "hysteresis": "torque-sensor hysteresis", "lost_motion": "lost motion after reversals",
         "ripple": "harmonic-drive torque ripple", "sensor_offset_gain": "torque-sensor offset / gain error",
         "sensor_offset": "torque-sensor offsets", "sensor_gain": "torque-sensor gain error",
         "torque_noise": "torque-sensor noise", "encoder_noise": "position-encoder noise",
         "elasticity": "joint elasticity (deflection unseen by the position sensor)",
         "rigid_body": "rigid-body (inertial) parameter error", "payload": "an unmodelled payload at the flange",
         "signal_lag": "a time lag between measured and modelled torque (filter delay)",
         "offset_drift": "a drifting torque-sensor offset", "friction_warmup": "friction fading as the joints warm up",
         "rotor_inertia": "rotor (armature) inertia", "presliding": "pre-sliding friction (before gross sliding)",
         "motor_friction": "motor-side friction (viscous + Coulomb on the motor velocities)",
         "drive_offset": "constant drive-torque offsets",
         "load_friction": "load-dependent friction (a Coulomb level growing with the transmitted torque)"}

_DRIVE_WORDS = {"sensor_offset_gain": "drive-torque offset / gain error (torque-constant error)",
                "sensor_gain": "drive-torque gain error (torque-constant error)",
                "sensor_offset": "drive-torque offsets", "torque_noise": "drive-torque (motor-current) noise",
                "offset_drift": "a drifting drive-torque offset"}


def plain_names(tau_kind: str = "link_sensor") -> dict[str, str]:
    """Plain-language names of the candidates for a τ of kind ``tau_kind`` (``link_sensor`` | ``drive``,
    :func:`proprio.diagnosis.candidates.drive.tau_kind`): a drive torque (current × torque constant × gear ratio) has no
    torque sensor, so its gain, offset and noise are named for the drive, not for a sensor."""
    return {**PLAIN, **_DRIVE_WORDS} if tau_kind == "drive" else dict(PLAIN)


def _total(rmse: np.ndarray) -> float:
    """RMS over the joints of per-joint RMS values [N·m]."""
    return float(np.sqrt((np.asarray(rmse) ** 2).mean()))


def _join(words: Sequence[str]) -> str:
    words = list(words)
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def verdict_sentence(att: Attribution, tau_kind: str = "link_sensor") -> str:
    """The verdict in ONE sentence (≤ :data:`MAX_VERDICT_CHARS`): the held-out gap before and after, what was named,
    what stays undecided and what remains; every number is on the held-out data (as the summary table's)."""
    plain = plain_names(tau_kind)
    tot0 = _total(att.rmse_before)
    share = att.rmse_before ** 2 / max(float((att.rmse_before ** 2).sum()), 1e-300)
    j0 = int(np.argmax(share))
    where = f" (mostly {att.joint_names[j0]}: {100 * share[j0]:.0f} % of the squared error)" if share[j0] > 0.3 else ""
    named = [plain.get(st.name, st.name) + (" (or a tied effect)" if st.tied else "") for st in att.physical_steps]
    u = att.undecided
    if named:
        fin = att.steps[-1].rmse_after
        less = 100 * (1 - float((fin ** 2).sum()) / max(float((att.rmse_before ** 2).sum()), 1e-300))
        out = (f"On the held-out data the model's torque gap of {tot0:.3g} N·m RMS{where} falls to "
               f"{_total(fin):.3g} N·m RMS ({less:.0f} % less squared error) once {_join(named)} "
               f"{'is' if len(named) == 1 else 'are'} added")
        if u is not None:
            out += (f"; whether {plain.get(u.name, u.name)} adds is undecided (≈ {u.more_s:.0f} s more held-out "
                    "data would decide)")
    elif u is not None:
        out = (f"Undecided: on the held-out data the model's torque gap is {tot0:.3g} N·m RMS{where} and "
               f"{plain.get(u.name, u.name)} leads ({100 * u.gain:.0f} % held-out gain, t = {u.t_stat:.2g} < "
               f"{u.t_crit:.2g}), but about {u.more_s:.0f} s more held-out data are needed to decide")
    else:
        out = (f"No candidate effect shrinks the model's held-out torque gap of {tot0:.3g} N·m RMS{where} "
               "significantly")
    rs = att.residual
    if rs.white:
        out += "; what remains is white noise"
    elif rs.structured_time.any() or rs.structured_state.any():
        js = [att.joint_names[j] for j in np.flatnonzero(rs.structured_time | rs.structured_state)]
        on = "every joint" if len(js) == len(att.joint_names) > 1 else _join(js)
        out += f"; what remains on {on} is structured (see What remains unexplained)"
    out += "."
    return out if len(out) <= MAX_VERDICT_CHARS else out[:MAX_VERDICT_CHARS - 1] + "…"


@dataclass
class SummaryRow:
    """One row of the report's summary table: ``effect`` (plain name), ``joints`` it acts on, ``gap`` (the held-out
    gap before → after it [N·m RMS over the joints], or "—"), ``gain`` (held-out gain), ``sure`` (named / tied
    with … / undecided with the seconds that would decide / what kind of finding)."""
    effect: str
    joints: str
    gap: str
    gain: str
    sure: str

    HEADER = ("effect", "joints", "held-out gap before → after [N·m RMS]", "held-out gain", "how sure")

    def cells(self) -> list[str]:
        return [self.effect, self.joints, self.gap, self.gain, self.sure]


def _acting_joints(before: np.ndarray, after: np.ndarray, names: Sequence[str], share: float = 0.1) -> str:
    """The joints that carry at least ``share`` of a step's drop of the held-out squared error, largest first."""
    drop = np.maximum(np.asarray(before) ** 2 - np.asarray(after) ** 2, 0.0)
    if not drop.sum() > 0:
        return "—"
    order = [j for j in np.argsort(-drop) if drop[j] >= share * drop.sum()]
    return ", ".join(names[j] for j in order)


def summary_rows(att: Attribution, tau_kind: str = "link_sensor") -> list[SummaryRow]:
    """The summary table's rows (module docstring), in the order the selection took the effects."""
    plain = plain_names(tau_kind)
    rows, prev = [], att.rmse_before
    mt = att.missing_term
    if mt is not None:                  # first: every effect below was fitted on such a log
        what = "gravity" if mt.term == "gravity" else "the rigid-body torque"
        rows.append(SummaryRow(f"the logged τ seems to exclude {what} (the drive may compensate it)",
                               ", ".join(att.joint_names[j] for j in mt.joints), "—", "—",
                               f"a finding: residual ≈ {', '.join(f'{a:+.2f}' for a in mt.coefficients)} × the "
                               f"modelled term, {100 * mt.explained:.0f} % of the held-out residual"))
    if att.rmse_raw is not None:        # the data's correction: the gap below is measured after it
        rows.append(SummaryRow("data path: " + ", ".join(plain.get(s.name, s.name) for s in att.data_path)
                               + " (the conditioning, not the robot)", "—",
                               f"{_total(att.rmse_raw):.3g} → {_total(att.rmse_before):.3g}", "—",
                               "the gap is reported after this correction"))
    first = len(rows)
    for st in att.steps:
        name = plain.get(st.name, st.name)
        if st.processing:
            name += " (data path, not the robot)"
        sure = (f"tied with {_join([plain.get(t, t) for t in st.tied])} (the data cannot tell them apart)"
                if st.tied else f"named (t = {st.t_stat:.1f} over held-out blocks)")
        rows.append(SummaryRow(name, _acting_joints(prev, st.rmse_after, att.joint_names),
                               f"{_total(prev):.3g} → {_total(st.rmse_after):.3g}", f"{100 * st.gain:.0f} %", sure))
        prev = st.rmse_after
    u = att.undecided
    if u is not None:
        provisional = _total(prev) * math.sqrt(max(1.0 - u.gain, 0.0))     # the gain is on the squared error
        rows.append(SummaryRow(plain.get(u.name, u.name), "—", f"{_total(prev):.3g} → ≈ {provisional:.3g} if taken",
                               f"{100 * u.gain:.0f} %",
                               f"undecided (t = {u.t_stat:.2g} < {u.t_crit:.2g}): ≈ {u.more_s:.0f} s more held-out "
                               "data would decide"))
    for f in att.noise:
        js = np.flatnonzero(np.asarray(f.rms) > 0)
        rows.append(SummaryRow(plain.get(f.name, f.name), ", ".join(att.joint_names[j] for j in js), "—",
                               "— (white)" if "white residual" in f.explanation else "— (raw τ floor)",
                               f"{f.explanation}: "
                               + ", ".join(f"{f.rms[j]:.2g}" for j in js) + " N·m"))
    tv = att.time_variation
    if tv is not None and tv.detected:
        js = np.flatnonzero(tv.joints)
        rows.append(SummaryRow(f"the gap changes over the session ({tv.kind})",
                               ", ".join(att.joint_names[j] for j in js), "—", "—",
                               f"time test p = {float(np.min(tv.p_value[js])):.2g}"))
    if len(rows) == first:
        rows.append(SummaryRow("nothing named", "—", f"{_total(att.rmse_before):.3g} → {_total(att.rmse_before):.3g}",
                               "0 %", "no candidate shrinks the held-out gap significantly"))
    return rows


def where_text(att: Attribution, gm: GapMap | None) -> str:
    """Where the held-out gap is: per joint (N·m and % of the signal RMS) and, from the gap map (all the data), the
    two cells where it concentrates."""
    rmse0, sig = att.rmse_before, att.signal_rms
    share = (rmse0 ** 2) / max(float((rmse0 ** 2).sum()), 1e-300)
    order = np.argsort(-share)
    where = ", ".join(f"{att.joint_names[j]} ({100 * share[j]:.0f} %)" for j in order[:3] if share[j] > 0.05)
    parts = [f"Against the held-out data the model's torque gap is {_total(rmse0):.3g} N·m RMS over the joints "
             f"(per joint {', '.join(f'{x:.2g}' for x in rmse0)} N·m, i.e. "
             f"{', '.join(f'{100 * x / max(s, 1e-12):.0f}' for x, s in zip(rmse0, sig))} % of the signal RMS); "
             f"most of the squared error sits in {where or 'no single joint'}."]
    if att.rmse_raw is not None:
        parts.append(att.data_path_text())
    if att.missing_term is not None:        # every effect below was fitted on such a log: say it first
        parts.append(att.missing_term.text(att.joint_names))
    hs = gm.hotspots(2) if gm is not None else []
    if hs:
        parts.append("Over all the data (training and held-out) it concentrates in "
                     + " and ".join(f"{j} at {b} ({f}, {c:.1f}× its average)" for j, f, b, _, c in hs) + ".")
    return " ".join(parts)


def effects_text(att: Attribution, tau_kind: str = "link_sensor") -> str:
    """How each named effect shrinks the held-out gap, the tied sets, and the undecided leader."""
    plain = plain_names(tau_kind)
    rmse0 = att.rmse_before
    parts = []
    if att.physical_steps:
        prev = rmse0
        sents = []
        for st in att.steps:
            if st.processing:
                prev = st.rmse_after
                continue
            name = plain.get(st.name, st.name)
            if st.tied:
                name += " (or, equally well, " + " or ".join(plain.get(t, t) for t in st.tied) + \
                    " — the data cannot tell them apart)"
            sents.append(f"{name} shrinks it from {_total(prev):.3g} to {_total(st.rmse_after):.3g} N·m RMS "
                         f"({100 * st.gain:.0f} % of the weighted held-out squared error)")
            prev = st.rmse_after
        parts.append("Adding " + "; then ".join(sents) + ".")
        fin = att.steps[-1].rmse_after
        parts.append(f"With {len(att.physical_steps)} effect(s) added the gap is {_total(fin):.3g} "
                     f"N·m RMS ({100 * (1 - float((fin ** 2).sum()) / float((rmse0 ** 2).sum())):.0f} % less "
                     "squared error).")
        parts += [a.text(plain) for a in tied_sets(att.ambiguity)]
    elif att.undecided is None:
        parts.append("No physical candidate shrinks the held-out gap significantly beyond what the signal "
                     "processing explains: the model explains the data as well as any of the candidates can.")
    parts += [p.text(plain) for p in att.position_only]
    if att.undecided is not None:
        parts.append(undecided_text(att, tau_kind))
    return " ".join(parts)


def remains_text(att: Attribution, tau_kind: str = "link_sensor") -> str:
    """What stays unexplained: a time dependence, the remaining residual's structure, unmodelled noise."""
    plain = plain_names(tau_kind)
    parts = []
    tv = att.time_variation
    if tv is not None and tv.detected:
        parts.append(tv.text[0].upper() + tv.text[1:] + ".")
    rs = att.residual
    if rs.white:
        parts.append("What remains is white (no autocorrelation, no dependence on the motion state): noise.")
    elif not (rs.structured_time.any() or rs.structured_state.any()):
        joints = [att.joint_names[j] for j in np.flatnonzero(~rs.white_joints)]
        parts.append(f"What remains on {', '.join(joints)} is not white (Ljung–Box p down to "
                     f"{float(rs.ljung_box_p.min()):.2g}, held-out R² against the motion state up to "
                     f"{float(rs.r2_state.max()):.2f}) but its structured part stays within the error the signal "
                     "conditioning explains: not a named effect"
                     + ("; whether it holds unmodelled noise is read from the raw τ's white floor (below)."
                        if att.noise else ", nor noise."))
    else:
        jt = [att.joint_names[j] for j in np.flatnonzero(rs.structured_time)]
        js = [att.joint_names[j] for j in np.flatnonzero(rs.structured_state)]
        bits = []
        if jt:
            bits.append(f"autocorrelated in time on {', '.join(jt)}")
        if js:
            bits.append(f"still predictable from the motion state on {', '.join(js)} (held-out R² up to "
                        f"{float(rs.r2_state.max()):.2f})")
        parts.append("What remains is structured — " + "; ".join(bits) + " — so part of the gap is an effect "
                     "outside the candidate set (or a candidate in a form the library does not model).")
        if not att.hints:
            parts.append("No few terms of the measured and modelled signals (τ, q, q̇, q̈, their harmonics, time) "
                         "explain a significant share of it on the held-out data: no hint.")
    for f in att.noise:
        joints = np.flatnonzero(f.rms > 0)
        parts.append(f"On {', '.join(att.joint_names[j] for j in joints)}: {f.explanation} — "
                     f"{plain.get(f.name, f.name)} of about "
                     f"{', '.join(f'{f.rms[j]:.2g}' for j in joints)} N·m is unmodelled.")
    return " ".join(parts)


def _why_not_taken(candidates: Sequence[str], att: Attribution, model_effects: Sequence[str],
                   plain: dict[str, str]) -> str:
    """Why the library effect a hint resembles was not (or was) taken: named, already in the model, tested and
    not significant, significant alone but explained by the named ones, or not among the candidates tested."""
    named = {st.name for st in att.steps} | {t for st in att.steps for t in st.tied}
    ranked = {r["name"]: r for r in att.ranking}
    for c in candidates:
        name = plain.get(c, c)
        if c in named:
            return (f"{name} was named; the hint is what its fitted law leaves on this joint (a form the law does not "
                    "have)")
        if c in model_effects:
            return f"the model already has {name}; the hint says its coefficients are off on this joint"
    for c in candidates:
        r = ranked.get(c)
        if r is not None:
            name = plain.get(c, c)
            if not r["significant"]:
                return (f"{name} was tested: alone it lowers the held-out error by {100 * r['gain']:.1f} % "
                        f"(t = {r['t']:.1f} over blocks), not significant over all the joints")
            return (f"{name} was significant alone ({100 * r['gain']:.0f} %) but not taken: the named effects "
                    "already explain what it would on the other joints")
    return f"{_join([plain.get(c, c) for c in candidates])} {'was' if len(candidates) == 1 else 'were'} not among " \
           "the candidates tested (--candidates)"


def hint_texts(att: Attribution, tau_kind: str = "link_sensor", model_effects: Sequence[str] = ()) -> list[str]:
    """One text per hint: what the remaining residual follows and, where a term is a library candidate's law on the
    joint, which effect it resembles and why that effect was not taken (:func:`_why_not_taken`); first, where the
    joints have names, which number is which (the hints count the joints from 1)."""
    plain = plain_names(tau_kind)
    out = []
    names = list(att.joint_names)
    if att.hints and names != [f"joint_{k + 1}" for k in range(len(names))]:
        out.append("Joints are numbered from 1 in the hints (q₃ is joint 3's angle): "
                   + ", ".join(f"joint {k + 1} = {nm}" for k, nm in enumerate(names)) + ".")
    for h in att.hints:
        text = h.text
        for term, cands in h.resembles:
            text += (f" {term} is the law of {' or '.join(plain.get(c, c) for c in cands)}: "
                     f"{_why_not_taken(cands, att, model_effects, plain)}.")
        out.append(text)
    return out


@dataclass
class OffsetAdvice:
    """A constant part of the remaining held-out residual beyond its noise, per joint: ``mean`` [N·m], ``t`` (the
    block means' t statistic), ``joints`` (0-based, the significant ones) and the advice ``text`` ("" when none)."""
    mean: np.ndarray
    t: np.ndarray
    joints: np.ndarray
    text: str


def _fitted_offset_sigma(att: Attribution, n: int) -> np.ndarray:
    """σ [N·m] per joint of a named offset's fit (0 where none): a fitted offset's held-out mean is off by its own
    estimation error, which the block test must allow for."""
    out = np.zeros(n)
    for name, (_, ci, names) in (att.steps[-1].params.items() if att.steps else ()):
        if name in ("sensor_offset", "sensor_offset_gain", "drive_offset"):
            for c, nm in zip(ci, names):
                if nm.startswith("offset["):
                    out[int(nm[7:-1]) - 1] = float(c) / 1.96
    return out


def offset_advice(att: Attribution, tau_kind: str = "link_sensor", alpha: float = 0.01) -> OffsetAdvice:
    """Whether the remaining held-out residual (after every named effect) has a constant part beyond its noise: per
    joint, a two-sided t-test of the means of the held-out time blocks (``att.block_s`` long: the selection's
    blocks, about twice the residual's correlation time, so the block means are nearly independent; a named
    offset's own fit σ added to the mean's variance) at ``α / n`` (Bonferroni over the joints). Where it rejects
    "mean 0" the model lacks an offset (or the offset moved between the training and held-out data), and the advice
    names the candidate that adds one."""
    means, n = [], len(att.joint_names)
    for t, e, p in zip(att.holdout_t, att.holdout_e, att.holdout_pred):
        r = e - p
        blk = np.floor((t - t[0]) / max(att.block_s, 1e-9)).astype(int)
        cnt = np.bincount(blk)
        keep = cnt > 0
        means.append(np.stack([np.bincount(blk, weights=r[:, j])[keep] / cnt[keep] for j in range(n)], axis=1))
    m = np.concatenate(means) if means else np.zeros((0, n))
    if len(m) < 3:
        return OffsetAdvice(np.zeros(n), np.zeros(n), np.zeros(0, int), "")
    mean = m.mean(axis=0)
    se2 = m.var(axis=0, ddof=1) / len(m) + _fitted_offset_sigma(att, n) ** 2
    t = np.where(se2 > 0, mean / np.sqrt(np.maximum(se2, 1e-300)), 0.0)
    p = 2 * stats.t.sf(np.abs(t), len(m) - 1)
    joints = np.flatnonzero(p < alpha / n)
    if not len(joints):
        return OffsetAdvice(mean, t, joints, "")
    cand = "drive_offset" if tau_kind == "drive" else "sensor_offset_gain"
    plain = plain_names(tau_kind)
    named = {st.name for st in att.steps} & {cand, "sensor_offset", "drive_offset"}
    what = (f"{plain.get(cand, cand)} was named, but the held-out level differs from the fitted one (a drifting "
            "offset?)" if named else
            f"the model lacks an offset there; {plain.get(cand, cand)} was tested but not named over all the joints — "
            "a model with offsets (identify: --offsets) would take it" if cand in att.candidates else
            f"the model lacks an offset: add {plain.get(cand, cand)} (--candidates ... {cand}; identify: --offsets)")
    text = ("The remaining held-out residual has a constant part beyond its noise on "
            + ", ".join(f"{att.joint_names[j]} ({mean[j]:+.3g} N·m, t = {t[j]:.1f} over {len(m)} blocks)"
                        for j in joints) + f": {what}.")
    return OffsetAdvice(mean, t, joints, text)


def verdict_text(att: Attribution, gm: GapMap | None, tau_kind: str = "link_sensor",
                 model_effects: Sequence[str] = (), advice: OffsetAdvice | None = None) -> str:
    """The whole plain-language explanation (the report's details, ``Diagnosis.explanation``): where the gap is,
    which effects explain it, how far it shrinks, what stays, the hints and the offset advice (candidates named for
    what ``tau_kind`` says τ is, :func:`plain_names`)."""
    parts = [where_text(att, gm), effects_text(att, tau_kind), remains_text(att, tau_kind)]
    hints = hint_texts(att, tau_kind, model_effects)
    if hints:
        parts.append(f"A sparse regression of what remains on the measured and modelled signals gives {len(att.hints)} "
                     "hint(s) — what the unexplained part follows, scored on the held-out data: " + " ".join(hints))
    parts.append((advice if advice is not None else offset_advice(att, tau_kind)).text)
    return "\n\n".join(p for p in parts if p)


@dataclass(frozen=True)
class Verdict:
    """The verdict step of a diagnosis (:func:`make_verdict`): the one ``sentence`` the report opens with, the whole
    ``explanation`` (:func:`verdict_text`) and the ``advice`` lines (what the person could do next)."""
    sentence: str
    explanation: str
    advice: list[str]


def make_verdict(att: Attribution, gm: GapMap | None, tau_kind: str = "link_sensor",
                 model_effects: Sequence[str] = ()) -> Verdict:
    """The :class:`Verdict` of ``att`` (``gm``: the gap map, ``None`` when the localisation failed)."""
    advice = offset_advice(att, tau_kind)
    return Verdict(verdict_sentence(att, tau_kind), verdict_text(att, gm, tau_kind, model_effects, advice),
                   [advice.text] if advice.text else [])


def undecided_text(att: Attribution, tau_kind: str = "link_sensor") -> str:
    """The sentence for a selection that stopped for want of held-out data (:class:`Undecided`)."""
    plain = plain_names(tau_kind)
    u = att.undecided
    return (f"Undecided: the held-out data are too few to decide{' whether more effects add' if att.physical_steps else ''}"
            f". The provisional leader is {plain.get(u.name, u.name)}, lowering the held-out error by "
            f"{100 * u.gain:.0f} % (t = {u.t_stat:.2g} over {u.n_blocks} blocks of {u.block_s:.2g} s, where "
            f"t ≥ {u.t_crit:.2g} is needed); about {u.more_s:.0f} s more held-out data of the same kind would decide.")


def data_and_processing_text(att: Attribution, tau_kind: str = "link_sensor") -> str:
    """The data path, apart from the physics: the conditioning of every recording, how much data there was and how
    the held-out test was made (and, for one cross-validated recording, how well the folds agree), the torque error
    the processing itself explains, the data-path candidates the selection found and the data's position-noise floor
    against the model's encoder noise (never reported as a cause)."""
    plain = plain_names(tau_kind)
    train_s, hold_s = att.data_seconds
    parts = [f"Data: {train_s:.1f} s for fitting and {hold_s:.1f} s held out, scored in time blocks of "
             f"{att.block_s:.2f} s (twice the residual's correlation time, within the limits the data length allows)."]
    if att.cv is not None:
        tops = [", ".join(x) or "nothing" for x in att.cv.fold_top]
        sure = "consistent" if att.cv.agreement >= 0.99 else ("partly consistent" if att.cv.agreement > 0 else
                                                               "not consistent")
        parts.append(f"No held-out recording was given: the recording was cut into {att.cv.n_blocks} blocks, "
                     f"alternate blocks fitted and scored, twice with the roles swapped. Fold 1 names {tops[0]}; "
                     f"fold 2 names {tops[1]} — {sure} ({100 * att.cv.agreement:.0f} % agreement). "
                     "The verdict is fold 1's.")
    parts += att.conditioning
    ratio = att.processing_sigma / np.maximum(att.rmse_before, 1e-12)
    parts.append("Torque error the conditioning itself explains (derivative errors through the rigid body and viscous "
                 "friction; the model's own Coulomb jump is not counted), per joint: "
                 + ", ".join(f"{x:.2g}" for x in att.processing_sigma) + " N·m RMS, against the model's held-out "
                 "gap before any candidate of " + ", ".join(f"{x:.2g}" for x in att.rmse_before) + " N·m RMS"
                 + (f" — on {', '.join(att.joint_names[j] for j in np.flatnonzero(ratio >= 0.5))} the derivatives "
                    "make up half the gap or more: take the verdict there with care" if np.any(ratio >= 0.5) else "")
                 + "; a physical effect must exceed it to be named.")
    for st in att.processing_steps:
        parts.append(f"Data path: {plain.get(st.name, st.name)} lowers the held-out error by "
                     f"{100 * st.gain:.0f} % — not a property of the robot: it {st.reason}.")
    for sup in att.superseded:
        parts.append(f"A stand-in, dropped: {plain.get(sup.name, sup.name)} was taken at step {sup.step}, but with "
                     f"{', '.join(plain.get(x, x) for x in sup.context) or 'the others'} named it adds "
                     f"{100 * sup.gain:.1f} % held-out gain — they explain what it did; the selection was run again "
                     "without it.")
    for name, gain, rms in att.below_floor:
        parts.append(f"Within the conditioning error: {plain.get(name, name)} lowers the held-out error by "
                     f"{100 * gain:.0f} %, but its held-out torque (≤ {rms:.2g} N·m RMS) stays within the error the "
                     "signal conditioning explains — not named, and not a data-path finding either.")
    if att.encoder is not None:
        parts.append(att.encoder.text(att.joint_names))
    return "\n\n".join(parts)
