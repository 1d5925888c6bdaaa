"""The registry of fittable joint effects (YAML key → class) and the builder of an ``effects:`` block."""
from __future__ import annotations

from proprio.effects.base import EffectConfigError, JointEffect
from proprio.effects.drive import Elasticity
from proprio.effects.friction import Stribeck, ViscousCoulomb
from proprio.effects.hysteresis import Hysteresis, LostMotion
from proprio.effects.sensor import EncoderNoise, Ripple, SensorOffsetGain, TorqueNoise
from proprio.effects.time_varying import FrictionWarmup, OffsetDrift

__all__ = ["EFFECTS", "make_effects"]

EFFECTS: dict[str, type[JointEffect]] = {cls.name: cls for cls in (
    ViscousCoulomb, Stribeck, Hysteresis, LostMotion, Ripple, SensorOffsetGain, TorqueNoise, EncoderNoise, Elasticity,
    OffsetDrift, FrictionWarmup)}


def make_effects(config: dict | None, n: int) -> list[JointEffect]:
    """Build the effects of a YAML ``effects:`` mapping ``{name: block}``: library effects in registry order, then
    plugins (``"package.module:Class"`` keys, :mod:`proprio.effects.plugins`) in the mapping's
    order.

    Unknown names raise :class:`EffectConfigError` listing the valid ones (the payload and the motor side have the
    twin's own ``payload`` and ``drive`` blocks); a bad plugin raises it naming the plugin and the problem.
    """
    from proprio.effects.plugins import is_plugin_path, resolve_effect    # plugins resolve library names here

    config = config or {}
    if not isinstance(config, dict):
        raise EffectConfigError(f"effects must be a mapping {{name: parameters}}, got {config!r}")
    unknown = sorted(k for k in config if k not in EFFECTS and not is_plugin_path(str(k)))
    if unknown:
        hint = " (the payload has its own top-level 'payload' block)" if "payload" in unknown else ""
        raise EffectConfigError(f"unknown joint effect(s) {unknown}{hint}; valid effects: {sorted(EFFECTS)} or a "
                                "plugin 'package.module:Class'")
    plugins = {k: resolve_effect(k) for k in config if is_plugin_path(str(k))}
    names = [cls.name for cls in plugins.values()]
    twice = sorted({k for k in names if names.count(k) > 1})
    if twice:
        raise EffectConfigError(f"plugins {sorted(plugins)}: effect name(s) {twice} given more than once")
    return [cls.from_config(config[name], n) for name, cls in EFFECTS.items() if name in config] + \
        [cls.from_config(config[key], n) for key, cls in plugins.items()]
