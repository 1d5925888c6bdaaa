"""The twin's sensors as laws over a piece of motion with explicit state: the link-side joint torque sensor
(:class:`TorqueSensor`), the joint position encoder (:class:`PositionSensor`), and the reversal state of the
path-dependent effects between pieces (:class:`PathEffects`).

A motion can be measured at once (``carry=None``: the piece is the whole motion) or piece by piece, each call taking
the state the previous one returned — a vector of numbers, which the twin's Diagram keeps as Drake discrete state
(:mod:`proprio.diagrams.twin_chain`). Both give the same samples (tests): the reversal travel and the Dahl law
continue their segments across pieces (:class:`proprio.reversals.ReversalCarry`,
:class:`~proprio.effects.dahl.DahlCarry`) and every effect draws from its own random stream (:mod:`proprio.random_streams`, named by the effect).

Torque sensor chain (thesis §2.1): ``τ_meas = (1 + g)·(τ_J + τ_hyst + τ_lost + τ_ripple) + o + o_d(t) + noise``,
i.e. the strain-gauge effects act on the transmitted τ_J, the gain/offset error on everything the gauge sees, a
drifting offset ``o_d`` (``offset_drift``, on the session clock ``MotionSignals.t``) adds to it, and white noise is
added last. Sensor-side plugins (:mod:`proprio.effects.plugins`) act with the strain-gauge effects, after the
library's, on the transmitted τ_J (``s.tau``); a plugin sees one piece at a time, with the carried reversal travel
(:func:`~proprio.effects.base.motion_reversal_travel`) but no other state. Every contribution is returned separately
(the twin's ``tau_<effect>`` truth channels).
"""
from __future__ import annotations

import numpy as np

from proprio.effects.base import JointEffect, motion_reversal_travel, reversal_key
from proprio.effects.dahl import DahlCarry, DahlEffect
from proprio.effects.hysteresis import LostMotion
from proprio.effects.sensor import EncoderNoise, SensorOffsetGain, TorqueNoise
from proprio.effects.time_varying import OffsetDrift
from proprio.random_streams import STATE_SIZE, generator_from_state, generator_state, stream
from proprio.reversals import ReversalCarry, reversal_travel
from proprio.signals import MotionSignals

__all__ = ["PathEffects", "PathPiece", "TorqueSensor", "PositionSensor"]

_GAUGE_ORDER = ("hysteresis", "lost_motion", "ripple")
_SENSOR_LIBRARY = ("sensor_offset_gain", "offset_drift", "torque_noise")   # library sensor effects past the gauge


class PathEffects:
    """The reversal-dependent effects among ``effects`` (the Dahl law's and lost motion) for ``n`` joints, and their
    state between pieces of a motion as ``[size]`` numbers: a started flag, a :class:`ReversalCarry` per distinct
    deadband ``reversal_velocity``, a :class:`DahlCarry` per Dahl effect."""

    def __init__(self, effects: list[JointEffect], n: int):
        self.n = n
        path = [e for e in effects if isinstance(e, (DahlEffect, LostMotion))]
        self.deadbands: dict[tuple, np.ndarray] = {}
        for e in path:
            self.deadbands.setdefault(reversal_key(e.reversal_velocity), np.asarray(e.reversal_velocity, dtype=float))
        self.dahl = [e.name for e in path if isinstance(e, DahlEffect)]
        self.size = 1 + 5 * n * len(self.deadbands) + 2 * n * len(self.dahl)

    def start(self) -> np.ndarray:
        """The state before a motion (not started: the first piece starts at its first sample)."""
        return np.zeros(self.size)

    def begin(self, s: MotionSignals, state: np.ndarray) -> "PathPiece":
        """Segment the piece ``s`` at reversals, continuing ``state``; its travels are left in ``s.derived`` where
        the effects (and :func:`motion_reversal_travel`) find them."""
        return PathPiece(self, s, state)


class PathPiece:
    """One piece of motion segmented with the carried state (:meth:`PathEffects.begin`): :meth:`torque` evaluates an
    effect on it, :meth:`end` is the state after it."""

    def __init__(self, path: PathEffects, s: MotionSignals, state: np.ndarray):
        self.path, n = path, path.n
        started = bool(state[0])
        ends = []
        for k, (key, eps) in enumerate(path.deadbands.items()):
            carry = ReversalCarry.from_vector(state[1 + 5 * n * k:1 + 5 * n * (k + 1)]) if started else None
            rt = reversal_travel(s.q, s.qd, eps if eps.ndim else float(eps), carry)
            s.derived[key] = rt
            ends.append(rt.end.vector())
        d0 = 1 + 5 * n * len(path.deadbands)
        self.dahl_in = {name: DahlCarry.from_vector(state[d0 + 2 * n * k:d0 + 2 * n * (k + 1)]) if started else None
                        for k, name in enumerate(path.dahl)}
        self.dahl_out: dict[str, DahlCarry] = {}
        self._reversal_end = ends

    def torque(self, eff: JointEffect, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        """``eff``'s contribution ``[N, n]`` N·m over the piece ``s``."""
        if isinstance(eff, DahlEffect):
            tau, self.dahl_out[eff.name] = eff.torque_carried(s, motion_reversal_travel(s, eff.reversal_velocity),
                                                              self.dahl_in[eff.name])
            return tau
        return eff.torque(s, rng)

    def end(self) -> np.ndarray:
        """The state after the piece (every Dahl effect must have been evaluated)."""
        return np.concatenate([[1.0], *self._reversal_end, *(self.dahl_out[k].vector() for k in self.path.dahl)])


class TorqueSensor:
    """The joint torque sensor of ``n`` joints: the sensor-side torque effects of a twin, applied in the physical order
    above, each random effect drawing from its stream under ``seed``."""

    def __init__(self, effects: list[JointEffect], n: int, seed: int = 0):
        bad = [e.name for e in effects if e.place != "sensor" or isinstance(e, EncoderNoise)]
        if bad:
            raise ValueError(f"TorqueSensor: {bad} are not torque-sensor effects")
        by_name = {e.name: e for e in effects}
        library = set(_GAUGE_ORDER) | set(_SENSOR_LIBRARY)
        # the library's strain-gauge effects in their order, then sensor-side plugins in the config's order
        self.gauge = [by_name[k] for k in _GAUGE_ORDER if k in by_name] + \
            [e for e in effects if e.name not in library]
        self.offset_gain: SensorOffsetGain | None = by_name.get("sensor_offset_gain")
        self.drift: OffsetDrift | None = by_name.get("offset_drift")
        self.noise: TorqueNoise | None = by_name.get("torque_noise")
        self.order = self.gauge + [e for e in (self.offset_gain, self.drift, self.noise) if e is not None]
        self.n, self.seed = n, int(seed)
        self.path = PathEffects(self.order, n)
        # the effects that may draw: the noise and any plugin (the library's other sensor effects are deterministic)
        self.random = [e for e in self.order if isinstance(e, TorqueNoise) or e.name not in library]
        self.size = self.path.size + STATE_SIZE * len(self.random)

    def start(self) -> np.ndarray:
        """The state ``[size]`` before a motion: path state, then the stream of each effect that may draw."""
        return np.concatenate([self.path.start()] + [generator_state(stream(self.seed, e.name)) for e in self.random])

    def measure(self, s: MotionSignals, tau_j: np.ndarray, carry: np.ndarray | None = None
                ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
        """Measured torque ``[N,n]`` N·m for true link motion ``s`` and true transmitted torque ``tau_j``, the
        contribution of each effect (keys = effect names) and the state after it; ``carry``: the state after the
        motion's previous piece (default: :meth:`start`, ``s`` is the whole motion)."""
        carry = self.start() if carry is None else carry
        p = self.path.size
        rngs = {e.name: generator_from_state(carry[p + STATE_SIZE * k:p + STATE_SIZE * (k + 1)])
                for k, e in enumerate(self.random)}
        s = s.with_tau(tau_j)
        piece = self.path.begin(s, carry[:p])
        parts: dict[str, np.ndarray] = {}
        seen = tau_j.copy()
        for eff in self.gauge:
            parts[eff.name] = piece.torque(eff, s, rngs.get(eff.name))
            seen += parts[eff.name]
        if self.offset_gain is not None:
            gain = self.offset_gain
            parts[gain.name] = piece.torque(gain, s.with_tau(seen), rngs.get(gain.name))
            seen = seen + parts[self.offset_gain.name]
        for eff in (self.drift, self.noise):
            if eff is not None:
                parts[eff.name] = piece.torque(eff, s, rngs.get(eff.name))
                seen = seen + parts[eff.name]
        out = np.concatenate([piece.end()] + [generator_state(rngs[e.name]) for e in self.random])
        return seen, parts, out


class PositionSensor:
    """The link-side joint position sensor of ``n`` joints: noise + quantisation (ideal without an ``encoder_noise``
    effect), its noise from the ``encoder_noise`` stream under ``seed``."""

    def __init__(self, encoder: EncoderNoise | None, n: int, seed: int = 0):
        self.encoder, self.n, self.seed = encoder, n, int(seed)
        self.size = STATE_SIZE

    def start(self) -> np.ndarray:
        return generator_state(stream(self.seed, EncoderNoise.name))

    def measure(self, q: np.ndarray, carry: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Measured positions ``[N,n]`` rad and the state after them (``carry``: as :meth:`TorqueSensor.measure`)."""
        carry = self.start() if carry is None else carry
        if self.encoder is None:
            return q.copy(), carry
        rng = generator_from_state(carry)
        return self.encoder.measure(q, rng), generator_state(rng)
