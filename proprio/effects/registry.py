"""The registry of the library's fittable joint effects: YAML key → class.

This module knows only the library; effects beyond it (plugins, their consent and the builder of a whole
``effects:`` block) live in :mod:`proprio.effects.plugins`, which imports this one and never the other way round."""
from __future__ import annotations

from proprio.effects.base import JointEffect
from proprio.effects.dahl import PreSliding
from proprio.effects.drive import Elasticity
from proprio.effects.friction import LoadFriction, Stribeck, ViscousCoulomb
from proprio.effects.hysteresis import Hysteresis, LostMotion
from proprio.effects.sensor import EncoderNoise, Ripple, SensorOffsetGain, TorqueNoise
from proprio.effects.time_varying import FrictionWarmup, OffsetDrift

__all__ = ["EFFECTS"]

EFFECTS: dict[str, type[JointEffect]] = {cls.name: cls for cls in (
    ViscousCoulomb, Stribeck, Hysteresis, LostMotion, Ripple, SensorOffsetGain, TorqueNoise, EncoderNoise, Elasticity,
    OffsetDrift, FrictionWarmup, PreSliding, LoadFriction)}
