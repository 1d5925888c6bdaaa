"""The plain-language verdict of a diagnosis: where the gap is, which effects explain it, how far it shrinks and
what stays unexplained."""
from __future__ import annotations

import numpy as np

from proprio.diagnosis.selection.ambiguity import tied_sets
from proprio.diagnosis.localisation import GapMap
from proprio.diagnosis.attribution import Attribution

__all__ = ["PLAIN", "plain_names", "verdict_text", "undecided_text", "data_and_processing_text"]

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


def verdict_text(att: Attribution, gm: GapMap, tau_kind: str = "link_sensor") -> str:
    """One plain-language paragraph: where the gap is, which effects explain it, how far it shrinks, what stays
    (candidates named for what ``tau_kind`` says τ is, :func:`plain_names`)."""
    plain = plain_names(tau_kind)
    rmse0, sig = att.rmse_before, att.signal_rms
    tot0 = float(np.sqrt((rmse0 ** 2).mean()))
    share = (rmse0 ** 2) / max(float((rmse0 ** 2).sum()), 1e-300)
    order = np.argsort(-share)
    where = ", ".join(f"{att.joint_names[j]} ({100 * share[j]:.0f} %)" for j in order[:3] if share[j] > 0.05)
    parts = [f"Against the held-out data the model's torque gap is {tot0:.3g} N·m RMS over the joints "
             f"(per joint {', '.join(f'{x:.2g}' for x in rmse0)} N·m, i.e. "
             f"{', '.join(f'{100 * x / max(s, 1e-12):.0f}' for x, s in zip(rmse0, sig))} % of the signal RMS); "
             f"most of the squared error sits in {where or 'no single joint'}."]
    if att.rmse_raw is not None:
        parts.append(att.data_path_text())
    if att.missing_term is not None:        # every effect below was fitted on such a log: say it first
        parts.append(att.missing_term.text(att.joint_names))
    hs = gm.hotspots(2)
    if hs:
        parts.append("It concentrates in " + " and ".join(f"{j} at {b} ({f}, {c:.1f}× its average)"
                                                         for j, f, b, _, c in hs) + ".")
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
            a = float(np.sqrt((prev ** 2).mean()))
            b = float(np.sqrt((st.rmse_after ** 2).mean()))
            sents.append(f"{name} shrinks it from {a:.3g} to {b:.3g} N·m RMS "
                         f"({100 * st.gain:.0f} % of the weighted held-out squared error)")
            prev = st.rmse_after
        parts.append("Adding " + "; then ".join(sents) + ".")
        fin = att.steps[-1].rmse_after
        parts.append(f"With {len(att.physical_steps)} effect(s) added the gap is {float(np.sqrt((fin ** 2).mean())):.3g} "
                     f"N·m RMS ({100 * (1 - float((fin ** 2).sum()) / float((rmse0 ** 2).sum())):.0f} % less "
                     "squared error).")
        parts += [a.text(plain) for a in tied_sets(att.ambiguity)]
    elif att.undecided is None:
        parts.append("No physical candidate shrinks the held-out gap significantly beyond what the signal "
                     "processing explains: the model explains the data as well as any of the candidates can.")
    parts += [p.text(plain) for p in att.position_only]
    if att.undecided is not None:
        parts.append(undecided_text(att, tau_kind))
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
                     "conditioning explains: neither noise nor a named effect.")
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
    if att.hints:
        parts.append(f"A sparse regression of what remains on the measured and modelled signals gives "
                     f"{len(att.hints)} hint(s) — hints about what the unexplained part follows, scored on the "
                     "held-out data, not library effects: " + " ".join(h.text for h in att.hints))
    for f in att.noise:
        joints = np.flatnonzero(f.rms > 0)
        parts.append(f"On {', '.join(att.joint_names[j] for j in joints)} the remaining residual is white and larger "
                     f"than the model's own noise: {plain.get(f.name, f.name)} of about "
                     f"{', '.join(f'{f.rms[j]:.2g}' for j in joints)} N·m is unmodelled.")
    return " ".join(parts)


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
