"""The torque sensor's reversal and ripple terms of an identified backbone: the twin's sensor laws, linear in their
amplitudes once the motion is given, as extra columns of the identification (grey box: the diagnosis names the
effects, the backbone carries their laws).

Per joint, on the measured (conditioned) motion ``q, q̇`` [rad, rad/s] and the a-priori model's link torque
``τ_prior = Y(q, q̇, q̈) φ_prior`` [N·m] (the robot description's rigid body and friction, the torque the sensor
transmits as far as it is known before the fit; its magnitude is the load of the load gains):

* ``gain``: the sensor's gain error ``g`` [-] (measured = (1 + g)·τ, :class:`proprio.effects.SensorOffsetGain`), its
  column ``τ_prior`` (linear to first order in g). A gain common to all joints is the rigid body's overall scale (the
  same torques): the identification settles that direction with a weak prior (:data:`GAIN_PRIOR_STD`, the
  diagnosis' prior on the same effect), so the gains it reports are relative to the rigid body it identifies, and
  its predictions do not depend on the choice;
* ``hysteresis``, ``hysteresis_load``: the Dahl law of :class:`proprio.effects.Hysteresis` with the level ``1`` and
  ``|τ_prior|`` (:func:`proprio.effects.dahl.dahl_batch`: linear in the level, so ``a·col₁ + k·col₂`` is the law
  with the level ``a + k|τ_prior|``, a saturation and its load gain);
* ``lost_motion``, ``lost_motion_load``: :class:`proprio.effects.LostMotion` at unit amplitude, and times
  ``|τ_prior|``;
* ``ripple_sin``, ``ripple_cos``: :class:`proprio.effects.Ripple` (``sin``/``cos`` of ``h·N·q``), only when the
  robot description gives the gear ratios ``N`` (its ``drive`` block).

The nonlinear settings are the laws' defaults (saturation travel 6°, lost-motion window 1°, reversal deadband
2 mrad/s; :class:`SensorTermSettings`). The laws' state — the reversal segmentation
(:class:`~proprio.reversals.ReversalCarry`) and the two Dahl carries — is carried from one piece of a motion to the
next (:class:`SensorCarry`), so the batch over a whole sequence and the same sequence fed one sample at a time
(the estimation Diagram, the streaming estimator) are the same law; a sequence starts in the virgin state at its
first sample. The same ``τ_prior`` enters the identification and the prediction (the measured τ would put its noise
into the load columns and is not available to a prediction; the identified model's own torque would make the fit
nonlinear).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from proprio.effects.dahl import DahlCarry, dahl_batch
from proprio.effects.hysteresis import Hysteresis, LostMotion
from proprio.effects.sensor import Ripple, SensorOffsetGain
from proprio.reversals import ReversalCarry, reversal_travel
from proprio.signals import MotionSignals

__all__ = ["GAIN_PRIOR_STD", "SENSOR_TERMS", "RIPPLE_TERMS", "SENSOR_BOUNDS", "SensorTermSettings", "SensorCarry",
           "SensorTerms", "sensor_columns"]

GAIN_PRIOR_STD = SensorOffsetGain.prior_std["gain"]
"""σ [-] of the zero-mean prior on the gains (the diagnosis' prior on :class:`proprio.effects.SensorOffsetGain`)."""

SENSOR_TERMS = ("gain", "hysteresis", "hysteresis_load", "lost_motion", "lost_motion_load")
"""The reversal terms' extras (module docstring), in their column order."""
RIPPLE_TERMS = ("ripple_sin", "ripple_cos")
"""The ripple's extras (only with gear ratios)."""
SENSOR_BOUNDS = {"hysteresis": Hysteresis.parameters["saturation"][1:],
                 "hysteresis_load": Hysteresis.parameters["load_gain"][1:],
                 "lost_motion": LostMotion.parameters["amplitude"][1:],
                 "lost_motion_load": LostMotion.parameters["load_gain"][1:]}
"""``(lower, upper)`` of the sensor terms the effects bound (their own parameter bounds: levels ≥ 0, load gains in
``[0, MAX_LOAD_GAIN]``); the gain and the ripple are free (the physically consistent fit,
:func:`~proprio.identification.estimators.sdp`, keeps the others inside them)."""


@dataclass(frozen=True)
class SensorTermSettings:
    """The laws' fixed settings, each ``[n]``: ``saturation_travel`` [rad] (hysteresis), ``window`` [rad] (lost
    motion), ``reversal_velocity`` [rad/s] (the deadband of the reversal detection), ``gear_ratio`` [-] (ripple;
    ``None``: no ripple terms) and the ripple's ``harmonic`` (cycles per wave-generator revolution)."""
    saturation_travel: tuple[float, ...]
    window: tuple[float, ...]
    reversal_velocity: tuple[float, ...]
    gear_ratio: tuple[float, ...] | None = None
    harmonic: float = Ripple.settings["harmonic"][0]

    @classmethod
    def defaults(cls, n: int, gear_ratio: Sequence[float] | None = None) -> "SensorTermSettings":
        """The laws' default settings for ``n`` joints; ``gear_ratio [n]`` (e.g. the description's drive block)
        adds the ripple terms."""
        def full(x: float) -> tuple[float, ...]:
            return (float(x),) * n
        return cls(full(Hysteresis.parameters["saturation_travel"][0]), full(LostMotion.parameters["window"][0]),
                   full(Hysteresis.settings["reversal_velocity"][0]),
                   None if gear_ratio is None else tuple(float(abs(g)) for g in gear_ratio))

    @property
    def n(self) -> int:
        """The number of joints the settings are for."""
        return len(self.window)

    @property
    def terms(self) -> tuple[str, ...]:
        """The extras these settings give columns for, in order."""
        return SENSOR_TERMS + (RIPPLE_TERMS if self.gear_ratio is not None else ())

    def to_dict(self) -> dict:
        """The settings as plain lists and floats (the model file's ``meta.sensor_terms``; :meth:`from_dict`)."""
        return {"saturation_travel": list(self.saturation_travel), "window": list(self.window),
                "reversal_velocity": list(self.reversal_velocity),
                "gear_ratio": None if self.gear_ratio is None else list(self.gear_ratio), "harmonic": self.harmonic}

    @classmethod
    def from_dict(cls, d: dict) -> "SensorTermSettings":
        """The settings of :meth:`to_dict`'s dict; ``ValueError`` naming the field whose list is not as long as
        ``window`` (the number of joints)."""
        n = len(d["window"])
        for field in ("saturation_travel", "reversal_velocity", "gear_ratio"):
            if d.get(field) is not None and len(d[field]) != n:
                raise ValueError(f"sensor terms: {field} has {len(d[field])} entries, window has {n} (one per "
                                 "joint)")
        gear = d.get("gear_ratio")
        return cls(tuple(map(float, d["saturation_travel"])), tuple(map(float, d["window"])),
                   tuple(map(float, d["reversal_velocity"])), None if gear is None else tuple(map(float, gear)),
                   float(d.get("harmonic", Ripple.settings["harmonic"][0])))


@dataclass(frozen=True)
class SensorCarry:
    """The laws' state at the end of a piece of motion: the reversal segmentation and the Dahl carries of the unit
    and the load level (:func:`sensor_columns`)."""
    reversal: ReversalCarry
    unit: DahlCarry
    load: DahlCarry

    def vector(self) -> np.ndarray:
        """``[9n]``: the reversal carry (5n), then the two Dahl carries (2n each)."""
        return np.concatenate([self.reversal.vector(), self.unit.vector(), self.load.vector()])

    @classmethod
    def from_vector(cls, v: np.ndarray) -> "SensorCarry":
        """The carry of :meth:`vector`'s ``[9n]`` layout (``n = v.size // 9``)."""
        v = np.asarray(v, dtype=float)
        n = v.size // 9
        return cls(ReversalCarry.from_vector(v[:5 * n]), DahlCarry.from_vector(v[5 * n:7 * n]),
                   DahlCarry.from_vector(v[7 * n:]))


class _Laws:
    """The effect objects at unit amplitude with the settings' values (built once per settings)."""

    def __init__(self, st: SensorTermSettings):
        n = st.n
        self.eps = np.asarray(st.reversal_velocity)
        self.rho = Hysteresis(n, saturation_travel=np.asarray(st.saturation_travel)).rho
        self.lost = LostMotion(n, amplitude=1.0, window=np.asarray(st.window), reversal_velocity=self.eps)
        self.ripple = None if st.gear_ratio is None else [
            Ripple(n, sin_amplitude=a, cos_amplitude=1.0 - a, gear_ratio=np.asarray(st.gear_ratio),
                   harmonic=st.harmonic) for a in (1.0, 0.0)]


@functools.lru_cache(maxsize=16)
def _laws(settings: SensorTermSettings) -> _Laws:
    return _Laws(settings)


def sensor_columns(settings: SensorTermSettings, q: np.ndarray, qd: np.ndarray, prior: np.ndarray,
                   carry: SensorCarry | None = None) -> tuple[np.ndarray, SensorCarry]:
    """The columns ``[len(settings.terms), N, n]`` [N·m per unit amplitude] of the sensor terms (module docstring)
    over the piece ``q, q̇ [N,n]`` (rad, rad/s) with the a-priori link torque ``prior [N,n]`` [N·m] (the gain's
    column, and the load), continuing ``carry`` (default: the virgin state at ``q[0]``), and the state at its
    end."""
    laws = _laws(settings)
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    prior = np.asarray(prior, dtype=float)
    load = np.abs(prior)
    n = q.shape[1]
    c = carry or SensorCarry(ReversalCarry.start(q[0]), DahlCarry.virgin(n), DahlCarry.virgin(n))
    rt = reversal_travel(q, qd, laws.eps, c.reversal)
    unit, unit_end = dahl_batch(rt, np.ones_like(q), laws.rho, c.unit)
    loaded, load_end = dahl_batch(rt, load, laws.rho, c.load)
    s = MotionSignals(np.zeros(q.shape[0]), q, qd, np.zeros_like(q))
    lost = laws.lost.torque(s, travel=rt)
    cols = [prior, unit, loaded, lost, lost * load]
    if laws.ripple is not None:
        cols += [r.torque(s) for r in laws.ripple]
    return np.stack(cols), SensorCarry(rt.end, unit_end, load_end)


@dataclass(frozen=True)
class SensorTerms:
    """Identified sensor terms: the ``settings`` and the amplitude of each of their terms per joint
    (``coefficients [len(settings.terms)][n]``: N·m for the levels and the ripple, [-] for the load gains)."""
    settings: SensorTermSettings
    coefficients: tuple[tuple[float, ...], ...]

    def torque(self, q: np.ndarray, qd: np.ndarray, prior: np.ndarray, carry: SensorCarry | None = None
               ) -> tuple[np.ndarray, SensorCarry]:
        """The terms' torque ``[N,n]`` [N·m] over the piece ``q, q̇ [N,n]`` with the a-priori link torque ``prior
        [N,n]`` [N·m] continuing ``carry``, and the state at its end (:func:`sensor_columns`)."""
        cols, end = sensor_columns(self.settings, q, qd, prior, carry)
        return np.einsum("kin,kn->in", cols, np.asarray(self.coefficients)), end
