"""The candidate set a diagnosis tests (:func:`candidate_set`): every deterministic candidate the model lacks, chosen by
what its τ is, plus the user's plugins."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from proprio.diagnosis.candidates.base import (Candidate, EffectCandidate, ElasticityCandidate, EncoderNoiseCandidate,
                                               SignalLagCandidate, ripple_candidate)
from proprio.diagnosis.data import DiagnosisError, GapData, SimModel
from proprio.diagnosis.candidates.drive import DRIVE_CANDIDATES, DRIVE_ONLY, GAUGE_ONLY, DriveCandidate, tau_kind
from proprio.diagnosis.candidates.rigid_body import PayloadCandidate, RigidBodyCandidate
from proprio.effects import EFFECTS, JointEffect

__all__ = ["candidate_set"]


def candidate_set(model: SimModel, train: GapData, names: Sequence[str] | None = None,
                  plugins: Sequence[str | type[JointEffect]] = (), time_varying: bool = False) -> list[Candidate]:
    """All deterministic candidates the model lacks (or only ``names``, which must be among them), plus the user's
    ``plugins`` (plugin paths ``"package.module:Class"`` or ``JointEffect`` subclasses, tested alongside; a plugin
    path in ``names`` counts as one). What τ is decides the rest (:func:`tau_kind`): for drive torques the drive's
    terms (:data:`DRIVE_CANDIDATES`; an uncoupled motor's friction only when the model has link friction, else it is
    the ``viscous_coulomb`` candidate) and pre-sliding friction, never the gauge's effects (:data:`GAUGE_ONLY`); for a
    link-side torque sensor never those of :data:`DRIVE_ONLY`. The time-varying library effects are offered only when
    ``time_varying`` (the residual depends on the session time, :mod:`proprio.diagnosis.selection.time_variation`) or
    when named. Raises
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
