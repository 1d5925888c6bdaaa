"""Effect names beyond the library (plugins), the consent that lets one be imported, and the builder of an
``effects:`` block.

A plugin is a :class:`~proprio.effects.base.JointEffect` subclass outside the library, named by its path
``"package.module:Class"`` wherever a library effect name is accepted — a key of the twin YAML ``effects:`` mapping
or of a ``twin_patch.yaml``, ``proprio diagnose --candidate`` and ``--effects``. **A name never imports anything by
itself**: a plugin path resolves only when the user consented to it, in one of four ways —

* an installed package declares it as an entry point of the group ``proprio.effects`` (the ecosystem's plugin
  convention; in its ``pyproject.toml``: ``[project.entry-points."proprio.effects"]``
  ``hose_spring = "my_effects:HoseSpring"``), read with :func:`importlib.metadata.entry_points`;
* the user lists it on the command line, ``--allow-plugin package.module:Class`` (:func:`allow_plugins`; the list
  is passed on to worker processes in the environment variable ``PROPRIO_ALLOW_PLUGINS``, comma-separated, which a
  user may also set), or names it in ``proprio diagnose --candidate`` / ``--effects``;
* Python code registers the class object it already imported, :func:`register_plugin`;
* it is one of the plugins proprio ships itself (:data:`BUILTIN_PLUGINS`, :mod:`proprio.effects.open_world`).

Anything else is refused with an :class:`EffectConfigError` that says how to consent, before any import; a path must
be absolute (``a.b:C``, never ``.b:C``). :func:`make_effects` checks a whole ``effects:`` mapping (its type, every
name, every library block) before it imports the first plugin.

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
noise, so they may couple joints (e.g. cross-talk ``τ_meas,j += c_j τ_J,j+1``). Motor-side plugins are refused:
nothing of them reaches τ_J.
"""
from __future__ import annotations

import importlib
import os
from collections.abc import Iterable
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from proprio.effects.base import EffectConfigError, JointEffect
from proprio.effects.registry import EFFECTS

__all__ = ["PLUGIN_PLACES", "ENTRY_POINT_GROUP", "ALLOW_ENV", "BUILTIN_PLUGINS", "is_plugin_path", "allow_plugins",
           "register_plugin", "registered_plugins", "check_consent", "resolve_effect", "effect_key"]

PLUGIN_PLACES = ("link", "sensor")
ENTRY_POINT_GROUP = "proprio.effects"
ALLOW_ENV = "PROPRIO_ALLOW_PLUGINS"
BUILTIN_PLUGINS = tuple(f"proprio.effects.open_world:{c}" for c in (
    "TorqueCrossTalk", "PositionFriction", "CableSpring", "NeighbourDrag", "ConfigurationTorque"))

_CLASSES: dict[str, type[JointEffect]] = {}      # plugin path → class, once resolved or registered


def is_plugin_path(name: str) -> bool:
    """``True`` for a dotted plugin path ``"package.module:Class"`` (a library name has no colon)."""
    return ":" in name


def _check_path(name: Any) -> tuple[str, str]:
    """``(module, attribute path)`` of a syntactically valid, absolute plugin path, else :class:`EffectConfigError`."""
    module, _, attr = str(name).partition(":")
    if not all(p.isidentifier() for p in module.split(".")) or not all(p.isidentifier() for p in attr.split(".")):
        raise EffectConfigError(f"plugin {name!r}: expected an absolute path 'package.module:Class'")
    return module, attr


def _entry_points() -> dict[str, EntryPoint]:
    """The installed packages' ``proprio.effects`` entry points by plugin path (from metadata: nothing imported)."""
    return {f"{ep.module}:{ep.attr}": ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _allowed() -> set[str]:
    return {p.strip() for p in os.environ.get(ALLOW_ENV, "").split(",") if p.strip()}


def allow_plugins(paths: Iterable[str]) -> None:
    """Consent to import the plugins ``paths`` (``--allow-plugin``) when a config names them; nothing is imported
    here. The list goes into ``PROPRIO_ALLOW_PLUGINS`` so that worker processes inherit it."""
    paths = [str(p).strip() for p in paths]
    for p in paths:
        _check_path(p)
    os.environ[ALLOW_ENV] = ",".join(sorted(_allowed() | set(paths)))


def registered_plugins() -> list[str]:
    """Every plugin path a config may name now: shipped, entry points, allowed and registered ones."""
    return sorted(set(BUILTIN_PLUGINS) | set(_entry_points()) | _allowed() | set(_CLASSES))


def _validate(cls: Any, name: str) -> type[JointEffect]:
    if not (isinstance(cls, type) and issubclass(cls, JointEffect)):
        raise EffectConfigError(f"plugin {name!r}: {cls!r} is not a subclass of proprio.effects.JointEffect")
    missing = [k for k in ("name", "place", "linear") if not hasattr(cls, k)]
    if missing:
        raise EffectConfigError(f"plugin {name!r}: class attribute(s) {missing} are not set")
    if cls.place not in PLUGIN_PLACES:
        raise EffectConfigError(f"plugin {name!r}: place = {cls.place!r}; a plugin acts 'link'-side (in the joint "
                                "drive) or 'sensor'-side (in the torque sensor)")
    if cls.name in EFFECTS:
        raise EffectConfigError(f"plugin {name!r}: name = {cls.name!r} is a library effect's name; choose another")
    return cls


def register_plugin(cls: type[JointEffect]) -> str:
    """Register a plugin class that Python code already imported (consent by the code itself); returns its path
    ``"module:Class"``, the name configs and :func:`resolve_effect` then accept."""
    key = f"{cls.__module__}:{cls.__qualname__}" if isinstance(cls, type) else repr(cls)
    _CLASSES[key] = _validate(cls, key)
    return key


def check_consent(name: str) -> None:
    """Raise :class:`EffectConfigError` unless the plugin path ``name`` may be imported (shipped, registered as an
    entry point, allowed by the user); imports nothing."""
    _check_path(name)
    if name not in _CLASSES and name not in BUILTIN_PLUGINS and name not in _allowed() and \
            name not in _entry_points():
        raise EffectConfigError(
            f"plugin {name!r} is not registered: a config may only name a plugin, never import one; install it as a "
            f"'{ENTRY_POINT_GROUP}' entry point of its package or allow it with --allow-plugin {name}")


def _load(name: str) -> Any:
    """Import the consented plugin ``name``; any failure of the module's own code is one :class:`EffectConfigError`."""
    module_name, attr = _check_path(name)
    ep = _entry_points().get(name)
    try:
        if ep is not None:
            return ep.load()
        obj: Any = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise EffectConfigError(f"plugin {name!r}: module {module_name!r} cannot be imported ({exc})") from exc
    except Exception as exc:      # the plugin's own top-level code failed: the user's, reported in one line
        raise EffectConfigError(f"plugin {name!r}: module {module_name!r} cannot be imported "
                                f"({type(exc).__name__}: {exc})") from exc
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise EffectConfigError(f"plugin {name!r}: module {module_name!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    return obj


def resolve_effect(name: str) -> type[JointEffect]:
    """The effect class of a library name (``"hysteresis"``) or a consented plugin path (module docstring).

    Raises :class:`EffectConfigError` naming the problem: an unknown library name, a plugin nobody consented to
    (before any import), a module that cannot be imported, a missing class, a class that is not a ``JointEffect``
    subclass, a place other than link/sensor, or a plugin ``name`` that shadows a library effect."""
    if not isinstance(name, str) or not name:
        raise EffectConfigError(f"effect name must be a library name or 'package.module:Class', got {name!r}")
    if not is_plugin_path(name):
        if name not in EFFECTS:
            raise EffectConfigError(f"unknown effect {name!r}; valid effects: {sorted(EFFECTS)} or a registered "
                                    "plugin 'package.module:Class'")
        return EFFECTS[name]
    if name in _CLASSES:
        return _CLASSES[name]
    check_consent(name)
    _CLASSES[name] = _validate(_load(name), name)
    return _CLASSES[name]


def effect_key(effect: JointEffect | type[JointEffect]) -> str:
    """The key that names an effect in a YAML ``effects:`` mapping: its library name, or its plugin path (the path
    it was registered or resolved under)."""
    cls = effect if isinstance(effect, type) else type(effect)
    if EFFECTS.get(cls.name) is cls:
        return cls.name
    return next((k for k, c in _CLASSES.items() if c is cls), f"{cls.__module__}:{cls.__qualname__}")
