"""Identification from Recordings: stack the measured signals (the §4.1 preprocessing where a recording has no q̇/q̈),
identify the rigid-body backbone and validate it on other recordings (Table 4.4 layout)."""
from __future__ import annotations

import numpy as np

from proprio.identification.estimators import identify, torque_error_table
from proprio.identification.excitation import load_excitation_config
from proprio.signals import PreprocessConfig, differentiate

__all__ = ["identify_recordings", "stack_recordings"]


def stack_recordings(recs: list, trim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate ``q, qd, qdd, tau`` of Recordings, dropping ``trim`` samples at both ends of each (filter
    start-up). Recordings without ``qd``/``qdd`` get them by the §4.1 preprocessing chain (central differences +
    Butterworth, ``excitation.yaml``)."""
    cfg = PreprocessConfig.from_dict(load_excitation_config()["preprocessing"])
    parts = {k: [] for k in ("q", "qd", "qdd", "tau")}
    for rec in recs:
        if rec.n_samples <= 2 * trim:
            raise ValueError(f"recording with {rec.n_samples} samples is shorter than 2 × --trim {trim}")
        qd = rec.qd if rec.qd is not None else differentiate(rec.t, rec.q, cfg)
        qdd = rec.qdd if rec.qdd is not None else differentiate(rec.t, qd, cfg)
        sl = slice(trim, rec.n_samples - trim)
        for k, v in (("q", rec.q), ("qd", qd), ("qdd", qdd), ("tau", rec.tau)):
            parts[k].append(np.asarray(v)[sl])
    return tuple(np.concatenate(parts[k]) for k in ("q", "qd", "qdd", "tau"))


def identify_recordings(train_recs: list, validate_recs: list, robot, method: str = "ols", trim: int = 100,
                        offsets: bool = True, coulomb_velocity_scale: float = 0.02):
    """Identify ``robot`` (a RobotDescription: kinematics + a-priori inertials) on Recordings and validate on
    others. Returns ``(model, table_text)`` with the Table 4.4-style per-joint MSE/σ on training and validation."""
    train = stack_recordings(train_recs, trim)
    model = identify(robot, *train, method, coulomb_velocity_scale=coulomb_velocity_scale, offsets=offsets)
    parts = [torque_error_table(train[3], model.torque(*train[:3]), "training (Table 4.4 layout)")[0]]
    if validate_recs:
        val = stack_recordings(validate_recs, trim)
        parts.append(torque_error_table(val[3], model.torque(*val[:3]), "validation")[0])
    return model, "\n\n".join(parts)
