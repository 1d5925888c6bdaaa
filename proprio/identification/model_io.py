"""The identified rigid-body model: base parameters + a full standard parameter set, saved as one ``.npz``.

File layout (``np.savez``, ``allow_pickle=False``): arrays ``phi_b [r (+n per extra)]``, ``sigma_pct [r]``, ``phi [12n (+3n drive)]``,
``independent [r]``, ``dependent [p−r]``, ``beta [r, p−r]`` and ``meta`` — a JSON string with ``format``,
``robot`` (the description's name), ``robot_description`` (its ``proprio-robot/v1`` mapping, so the file rebuilds a
``MultibodyPlant`` on its own), ``method``, ``base_names``, ``standard_names``, ``coulomb_velocity_scale``,
``training_digest`` (sha256 of the training arrays), ``n_train_samples``, ``physically_consistent`` and ``extras``
(the per-joint unknowns after the base parameters, in order: ``offset`` [N·m], ``load_gain`` [-] of load-dependent
Coulomb friction, then the torque sensor's terms of :mod:`proprio.identification.sensor_terms`; a file without it
and ``r + n`` entries holds offsets) and, with sensor terms, ``sensor_terms`` (their settings).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proprio import friction_law
from proprio.description import RobotDescription, robot_from_dict
from proprio.io import atomic_path
from proprio.identification.base_parameters import BaseParameters
from proprio.identification.sensor_terms import RIPPLE_TERMS, SENSOR_TERMS, SensorTerms, SensorTermSettings
from proprio.identification.regressor import (
    PARAMS_PER_JOINT, RegressorGeometry, drive_from_parameters, friction_from_parameters, parameters_to_links,
    predict, regressor_buffer, regressor_geometry, standard_parameters)

__all__ = ["IdentifiedModel", "save_model", "load_model", "data_digest", "ModelFileError", "FORMAT"]

FORMAT = "proprio-identified-model/v1"


class ModelFileError(ValueError):
    """An identified-model file is missing a field or is malformed; the message names it."""


def data_digest(*arrays: np.ndarray) -> str:
    """sha256 over the bytes (and shapes) of the given arrays — the fingerprint of a training set."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a, dtype=float)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


@dataclass
class IdentifiedModel:
    """An identified inverse-dynamics backbone ``τ_RBD = K_b(q, q̇, q̈) φ_b`` (thesis eq. 4.23).

    ``phi`` is a full standard parameter vector with ``base.to_base(phi) == phi_b`` (for OLS/WLS: the a-priori set
    moved minimally onto the identified base parameters, possibly non-physical; for SDP: physically consistent).
    """
    description: RobotDescription
    base: BaseParameters
    phi_b: np.ndarray
    sigma_pct: np.ndarray
    phi: np.ndarray
    method: str
    coulomb_velocity_scale: float
    training_digest: str = ""
    n_train_samples: int = 0
    physically_consistent: bool = False
    extras: tuple[str, ...] = ()       # per-joint unknowns after the base parameters: "offset", "load_gain", sensor
    sensor: SensorTermSettings | None = None   # the settings of the sensor terms among the extras
    _geometry: RegressorGeometry | None = field(default=None, repr=False, compare=False)

    @property
    def n(self) -> int:
        return self.description.n

    def _extra(self, name: str) -> np.ndarray:
        """The per-joint block ``name`` of :attr:`extras` in ``phi_b`` (zeros when the fit had none)."""
        if name not in self.extras:
            return np.zeros(self.n)
        at = self.base.n_base + self.n * self.extras.index(name)
        return self.phi_b[at:at + self.n]

    @property
    def offsets(self) -> np.ndarray:
        """Identified per-joint torque offsets [N·m] (zeros when the fit had none)."""
        return self._extra("offset")

    @property
    def load_gain(self) -> np.ndarray:
        """Identified load gains [-] of load-dependent Coulomb friction (zeros when the fit had none)."""
        return self._extra("load_gain")

    @property
    def sensor_terms(self) -> SensorTerms | None:
        """The identified torque-sensor terms (:mod:`proprio.identification.sensor_terms`), ``None`` without."""
        if self.sensor is None:
            return None
        return SensorTerms(self.sensor, tuple(tuple(float(x) for x in self._extra(k)) for k in self.sensor.terms))

    @property
    def names(self) -> list[str]:
        """Names of the entries of ``phi_b``: the base parameters, then ``offset<j>`` / ``load_gain<j>`` per extra."""
        return list(self.base.names) + [f"{e}{j + 1}" for e in self.extras for j in range(self.n)]

    def torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """``τ_RBD [N, n]`` (rigid body + identified friction + offsets + sensor terms) [N·m] for ``q, qd, qdd [N, n]``
        (or ``[n]``). The sensor terms have state: the samples are one contiguous sequence from the virgin state at
        the first (:mod:`proprio.identification.sensor_terms`)."""
        single = np.ndim(q) == 1
        if self._geometry is None:
            self._geometry = regressor_geometry(self.description)
        buf = regressor_buffer(self.description, q, qd, qdd, self.coulomb_velocity_scale, self._geometry)
        full = np.zeros(self.base.n_standard)
        full[self.base.independent] = self.phi_b[:self.base.n_base]  # K_b φ_b = Y φ with φ_b in the base slots
        per = PARAMS_PER_JOINT
        tau = np.stack([buf[i, per * i:].T @ full[per * i:] for i in range(self.n)], axis=1) + self.offsets
        if "load_gain" in self.extras:      # τ = a + k|τ| sgn_s(q̇): solved exactly (proprio.friction_law)
            sign = friction_law.smooth_sign(np.atleast_2d(qd), self.coulomb_velocity_scale)
            tau = friction_law.load_from_net(tau, sign, self.load_gain)
        terms = self.sensor_terms
        if terms is not None:               # their gain column and load: the a-priori torque Y φ_prior (sensor_terms)
            prior = predict(buf, standard_parameters(self.description))
            tau = tau + terms.torque(np.atleast_2d(q), np.atleast_2d(qd), prior)[0]
        return tau[0] if single else tau

    def description_identified(self) -> RobotDescription:
        """The robot description with the identified link inertials and friction (rebuilds a MultibodyPlant when
        ``physically_consistent``). Torque offsets of a link-side sensor are a sensor property and are not part of
        it; a drive-torque arm's drive block takes the identified rotor inertias, motor friction and offsets."""
        links = parameters_to_links(self.phi, self.description)
        fv, fc = friction_from_parameters(self.phi, self.n)
        drive = drive_from_parameters(self.phi, self.description, self.offsets)
        return dataclasses.replace(self.description.with_inertials(links), friction_viscous=fv, friction_coulomb=fc,
                                   drive=drive)

    def parameter_table(self) -> str:
        """Base parameters with relative standard deviations, thesis Table 4.6 layout (one row per parameter)."""
        names = self.names
        width = max(len(s) for s in names)
        lines = [f"{'base parameter':<{width}}  {'value':>12}  {'sigma %':>9}"]
        for name, val, sig in zip(names, self.phi_b, self.sigma_pct):
            lines.append(f"{name:<{width}}  {val:>12.5g}  {sig:>9.2f}")
        return "\n".join(lines)


def save_model(model: IdentifiedModel, path: str | Path) -> Path:
    """Write ``model`` atomically to ``path`` (``.npz``)."""
    path = Path(path)
    meta: dict[str, Any] = {
        "format": FORMAT, "robot": model.description.name, "robot_description": model.description.to_dict(),
        "method": model.method, "base_names": list(model.base.names),
        "standard_names": list(model.base.standard_names), "coulomb_velocity_scale": model.coulomb_velocity_scale,
        "training_digest": model.training_digest, "n_train_samples": model.n_train_samples,
        "physically_consistent": model.physically_consistent, "extras": list(model.extras),
        "sensor_terms": None if model.sensor is None else model.sensor.to_dict(),
    }
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, phi_b=model.phi_b, sigma_pct=model.sigma_pct, phi=model.phi,
                     independent=model.base.independent, dependent=model.base.dependent, beta=model.base.beta,
                     meta=np.array(json.dumps(meta)))
    return path


def load_model(path: str | Path) -> IdentifiedModel:
    """Read a model written by :func:`save_model`; a missing or malformed field raises :class:`ModelFileError`."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"identified model not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("phi_b", "sigma_pct", "phi", "independent", "dependent", "beta", "meta")
                       if k not in z.files]
            if missing:
                raise ModelFileError(f"{path}: not an identified model, missing {', '.join(missing)}")
            arrays = {k: z[k] for k in z.files}
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise ModelFileError(f"{path}: not a readable .npz, truncated or corrupted ({exc})") from None
    except ValueError as exc:           # e.g. an object array: a pickle, never loaded
        if isinstance(exc, ModelFileError):
            raise
        raise ModelFileError(f"{path}: not an identified model ({exc})") from None
    try:
        meta = json.loads(str(arrays["meta"]))
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{path}: meta is not valid JSON ({exc})") from None
    if meta.get("format") != FORMAT:
        raise ModelFileError(f"{path}: meta.format is {meta.get('format')!r}, expected {FORMAT!r}")
    desc = robot_from_dict(meta["robot_description"], source=f"{path}:meta.robot_description")
    base = BaseParameters(meta["robot"], arrays["independent"].astype(int), arrays["dependent"].astype(int),
                          arrays["beta"], tuple(meta["standard_names"]), tuple(meta["base_names"]))
    n_extra = (arrays["phi_b"].size - base.n_base) // max(desc.n, 1)
    extras = tuple(meta.get("extras", ["offset"] * n_extra))
    known = ("offset", "load_gain") + SENSOR_TERMS + RIPPLE_TERMS
    if not set(extras) <= set(known):
        raise ModelFileError(f"{path}: meta.extras {list(extras)} are not among {', '.join(known)}")
    try:
        sensor = None if meta.get("sensor_terms") is None else SensorTermSettings.from_dict(meta["sensor_terms"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: meta.sensor_terms is malformed ({exc!r})") from None
    if (sensor.terms if sensor is not None else ()) != tuple(e for e in extras if e in known[2:]):
        raise ModelFileError(f"{path}: meta.extras {list(extras)} do not match meta.sensor_terms")
    if arrays["phi_b"].shape != (base.n_base + desc.n * len(extras),) or \
            arrays["phi"].shape != (base.n_standard,):
        raise ModelFileError(f"{path}: phi_b/phi shapes {arrays['phi_b'].shape}/{arrays['phi'].shape} do not match "
                             f"{base.n_base} base / {base.n_standard} standard parameters")
    return IdentifiedModel(desc, base, arrays["phi_b"], arrays["sigma_pct"], arrays["phi"], meta["method"],
                           float(meta["coulomb_velocity_scale"]), meta.get("training_digest", ""),
                           int(meta.get("n_train_samples", 0)), bool(meta.get("physically_consistent", False)),
                           extras, sensor)
