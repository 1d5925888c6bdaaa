"""User-defined joint effects (plugins): a :class:`~proprio.effects.base.JointEffect` subclass in any importable
module, named by its dotted path ``"package.module:Class"`` wherever a library effect name is accepted — a key of
the twin YAML ``effects:`` mapping, ``proprio diagnose --candidate`` and ``--effects``.

A plugin declares, like the library classes:

* ``name`` (its truth channel is ``tau_<name>``; must not be a library name), ``place`` (``"link"``: simulated in
  the twin's joint drive, acting on the motion; ``"sensor"``: applied by the torque sensor to the transmitted τ_J),
  ``linear`` (``True`` when :meth:`~JointEffect.regressor` is implemented);
* ``parameters`` (fitted; name → (default, lower, upper), per joint) and ``settings`` (fixed hyper-parameters);
* :meth:`~JointEffect.torque` ``(s: MotionSignals) -> [N, n]`` N·m, vectorised over samples, and — where it is
  linear in its parameters — :meth:`~JointEffect.regressor` ``-> [N, n, n_params]``.

Link-side plugins are evaluated by the twin every time step with the current state ``(t, q, q̇)``, ``q̈ = 0`` and
``tau = None``: **a link-side effect may depend on t, q and q̇ only** (not on q̈ or on the torque, which the step
has not computed yet). Sensor-side plugins see the whole logged motion and ``s.tau`` = the true transmitted τ_J;
their contribution is added after the library's strain-gauge effects and before the offset/gain error and the
noise, so they may couple joints
(e.g. cross-talk ``τ_meas,j += c_j τ_J,j+1``). Motor-side plugins are refused: nothing of them reaches τ_J.
"""
from __future__ import annotations

import importlib

from proprio.effects.base import EffectConfigError, JointEffect
from proprio.effects.registry import EFFECTS

__all__ = ["PLUGIN_PLACES", "is_plugin_path", "resolve_effect", "effect_key"]

PLUGIN_PLACES = ("link", "sensor")


def is_plugin_path(name: str) -> bool:
    """``True`` for a dotted plugin path ``"package.module:Class"`` (a library name has no colon)."""
    return ":" in name


def resolve_effect(name: str) -> type[JointEffect]:
    """The effect class of a library name (``"hysteresis"``) or a plugin path (``"package.module:Class"``).

    Raises :class:`EffectConfigError` naming the problem: an unknown library name, a module that cannot be
    imported, a missing class, a class that is not a ``JointEffect`` subclass, a place other than link/sensor, or a
    plugin ``name`` that shadows a library effect."""
    if not isinstance(name, str) or not name:
        raise EffectConfigError(f"effect name must be a library name or 'package.module:Class', got {name!r}")
    if not is_plugin_path(name):
        if name not in EFFECTS:
            raise EffectConfigError(f"unknown effect {name!r}; valid effects: {sorted(EFFECTS)} or a plugin "
                                    "'package.module:Class'")
        return EFFECTS[name]
    module_name, _, class_name = name.partition(":")
    if not module_name or not class_name:
        raise EffectConfigError(f"plugin {name!r}: expected 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise EffectConfigError(f"plugin {name!r}: module {module_name!r} cannot be imported ({exc})") from exc
    obj = module
    for part in class_name.split("."):
        if not hasattr(obj, part):
            raise EffectConfigError(f"plugin {name!r}: module {module_name!r} has no attribute {class_name!r}")
        obj = getattr(obj, part)
    if not (isinstance(obj, type) and issubclass(obj, JointEffect)):
        raise EffectConfigError(f"plugin {name!r}: {class_name} is not a subclass of proprio.effects.JointEffect")
    missing = [k for k in ("name", "place", "linear") if not hasattr(obj, k)]
    if missing:
        raise EffectConfigError(f"plugin {name!r}: class attribute(s) {missing} are not set")
    if obj.place not in PLUGIN_PLACES:
        raise EffectConfigError(f"plugin {name!r}: place = {obj.place!r}; a plugin acts 'link'-side (in the joint "
                                "drive) or 'sensor'-side (in the torque sensor)")
    if obj.name in EFFECTS:
        raise EffectConfigError(f"plugin {name!r}: name = {obj.name!r} is a library effect's name; choose another")
    return obj


def effect_key(effect: JointEffect | type[JointEffect]) -> str:
    """The key that names an effect in a YAML ``effects:`` mapping: its library name, or its plugin path."""
    cls = effect if isinstance(effect, type) else type(effect)
    if EFFECTS.get(cls.name) is cls:
        return cls.name
    return f"{cls.__module__}:{cls.__qualname__}"
