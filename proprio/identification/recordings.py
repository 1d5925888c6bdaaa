"""Identification from Recordings: every recording goes through the one conditioning path
(:mod:`proprio.conditioning`: uniform time base, zero-phase low-pass of q and τ, q̇ and q̈ by central differences),
the conditioned samples are stacked, the rigid-body backbone identified and validated on other recordings
(Table 4.4 layout)."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from proprio.conditioning import ConditionedSignals, ConditioningConfig, condition
from proprio.identification.estimators import identify, piece_slices, torque_error_table
from proprio.identification.regressor import drive_identified
from proprio.identification.sensor_terms import SensorTermSettings
from proprio.recording import Recording

__all__ = ["identify_recordings", "stack_recordings", "pieces", "piece_torque", "check_tau_kind", "TRIM_S",
           "TAU_KINDS"]

TAU_KINDS = ("link_sensor", "drive")
"""The values of a Recording's ``meta.tau_kind`` (written by ``proprio import``)."""

TRIM_S = 0.5
"""s, the default trim per end (filter start-up): the diagnosis' longest default (``proprio.diagnosis.data.MAX_TRIM_S``)
and the 100 samples identify dropped at the LWR 4+'s 200 Hz before its ``--trim`` was in seconds."""


def check_tau_kind(recs: Sequence[Recording], names: Sequence[str], robot) -> None:
    """Raise ``ValueError`` when a Recording's ``meta.tau_kind`` (``link_sensor`` | ``drive``, written by
    ``proprio import``) contradicts the robot description's ``drive.tau_kind`` (``link_sensor`` without a drive
    block): the regressor's drive columns follow the description, so the two must agree."""
    want = robot.drive.tau_kind if robot.drive is not None else "link_sensor"
    for name, rec in zip(names, recs):
        got = rec.meta.get("tau_kind")
        if got is not None and got not in TAU_KINDS:
            raise ValueError(f"{name}: meta.tau_kind {got!r} is unknown; valid: 'link_sensor' (τ from a joint-torque "
                             "sensor) or 'drive' (τ from the motor currents); set tau_kind in the import mapping and "
                             "import the log again")
        if got is not None and got != want:
            fix = ("add a 'drive:' block with tau_kind: drive (gear_ratio, coupling) to the robot description"
                   if got == "drive" else "set the description's drive.tau_kind to link_sensor")
            raise ValueError(f"{name}: meta.tau_kind is {got!r} but the robot description {robot.name!r} says "
                             f"{want!r}; {fix}")


def stack_recordings(recs: Sequence[Recording], trim_s: float, config: ConditioningConfig = ConditioningConfig()
                     ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], list[ConditionedSignals]]:
    """Condition each Recording and concatenate its ``q, qd, qdd, tau`` ``[N,n]``, dropping ``trim_s`` seconds at
    both ends (filter start-up; rounded to the conditioned grid) and the samples inside gaps of the log. Returns the
    stacked arrays and the conditioned signals (for their ``describe()`` line; :func:`pieces` gives the sample count
    each recording contributes)."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("q", "qd", "qdd", "tau")}
    conditioned = []
    for k, rec in enumerate(recs):
        cs = condition(rec, config)
        keep = _kept(cs, trim_s, k)
        for name in parts:
            parts[name].append(getattr(cs, name)[keep])
        conditioned.append(cs)
    return tuple(np.concatenate(parts[k]) for k in ("q", "qd", "qdd", "tau")), conditioned


def pieces(conditioned: Sequence[ConditionedSignals], trim_s: float) -> list[int]:
    """The sample count each of :func:`stack_recordings`' conditioned recordings contributes to the stack."""
    return [int(_kept(cs, trim_s, k).sum()) for k, cs in enumerate(conditioned)]


def piece_torque(model, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, counts: Sequence[int]) -> np.ndarray:
    """``model.torque`` ``[N,n]`` [N·m] over stacked recordings, each piece (``counts``: its samples, summing to N)
    its own sequence: the sensor terms' state restarts at each recording's first sample, as the fit has it
    (:mod:`proprio.identification.estimators`), instead of flowing from one recording into the next."""
    return np.concatenate([model.torque(q[k], qd[k], qdd[k]) for k in piece_slices(counts, np.shape(q)[0])])


def _kept(cs: ConditionedSignals, trim_s: float, k: int = 0) -> np.ndarray:
    """The samples of recording ``k``'s conditioned signals that :func:`stack_recordings` keeps."""
    trim = int(round(trim_s * cs.rate_hz))
    if cs.n_samples <= 2 * trim:
        raise ValueError(f"recording {k}: {cs.n_samples / cs.rate_hz:.3g} s are not more than 2 × --trim "
                         f"{trim_s:g} s")
    keep = np.zeros(cs.n_samples, dtype=bool)
    keep[trim:cs.n_samples - trim] = True
    return keep & cs.valid


def identify_recordings(train_recs: Sequence[Recording], validate_recs: Sequence[Recording], robot,
                        method: str = "ols", trim_s: float = TRIM_S, offsets: bool = True,
                        coulomb_velocity_scale: float | None = None,
                        conditioning: ConditioningConfig = ConditioningConfig(), load_friction: bool = False,
                        sensor: SensorTermSettings | None = None):
    """Identify ``robot`` (a RobotDescription: kinematics + a-priori inertials) on Recordings and validate on
    others. Returns ``(model, table_text)`` with the Table 4.4-style per-joint MSE/σ on training and validation,
    headed by each recording's conditioning line. ``trim_s`` [s]: dropped at both ends of every recording.
    ``coulomb_velocity_scale`` [rad/s]: the Coulomb smoothing
    (``None``: the library's, :mod:`proprio.friction_law`). A drive-torque arm (``robot.drive.tau_kind == 'drive'``) always
    fits the constant drive offsets with its drive columns. ``load_friction``: also the load gain of load-dependent
    Coulomb friction per joint; ``sensor``: the torque sensor's terms with these settings, each recording's from the
    virgin state at its first kept sample (:mod:`proprio.identification.estimators`)."""
    offsets = offsets or drive_identified(robot)
    train, cond_tr = stack_recordings(train_recs, trim_s, conditioning)
    counts = pieces(cond_tr, trim_s)
    model = identify(robot, *train, method, coulomb_velocity_scale=coulomb_velocity_scale, offsets=offsets,
                     load_friction=load_friction, sensor=sensor, pieces=counts)
    lines = sorted({f"{cs.describe()}" for cs in cond_tr})
    parts = ["\n".join(lines), torque_error_table(train[3], piece_torque(model, *train[:3], counts),
                                                  "training (Table 4.4 layout)")[0]]
    if validate_recs:
        val, cond_v = stack_recordings(validate_recs, trim_s, conditioning)
        parts[0] = "\n".join(sorted(set(lines) | {cs.describe() for cs in cond_v}))
        parts.append(torque_error_table(val[3], piece_torque(model, *val[:3], pieces(cond_v, trim_s)),
                                        "validation")[0])
    return model, "\n\n".join(parts)
