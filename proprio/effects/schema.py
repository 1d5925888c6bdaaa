"""The schema of an ``effects:`` block (twin YAML, twin patch, ``proprio diagnose --effects-config``), checked
against what each effect class declares before it is built — once: :func:`make_effects` checks
(:func:`check_effects_block`) and builds.

An effect's YAML keys are its declared ``parameters`` and ``settings`` (:class:`~proprio.effects.base.JointEffect`),
each also as ``<key>_deg`` (given in degrees), plus the class's optional ``yaml_keys`` (extra spellings its
``from_config`` converts, e.g. ripple's ``amplitude``/``phase_deg``). Each value is one number (every joint) or a list
of numbers, one per joint. An unknown effect name is an error naming the nearest library effect; an unknown key the
nearest declared key; a word where a number belongs or a list of the wrong length names the field. Ranges stay with
the class (``EffectConfigError`` naming the field)."""
from __future__ import annotations

from typing import Any

from proprio.effects.base import EffectConfigError, JointEffect
from proprio.effects.plugins import check_consent, is_plugin_path, resolve_effect
from proprio.effects.registry import EFFECTS
from proprio.typed_yaml import check_keys, join_key, nearest_hint, per_joint

__all__ = ["effect_yaml_keys", "check_effects_block", "check_effect_block", "make_effects"]


def effect_yaml_keys(cls: type[JointEffect]) -> list[str]:
    """The keys an effect's YAML block may hold (module docstring)."""
    declared = [*cls.parameters, *cls.settings]
    return declared + [f"{k}_deg" for k in declared] + list(getattr(cls, "yaml_keys", ()))


def check_effect_block(cls: type[JointEffect], block: Any, n: int, where: str,
                       error: type[Exception] = EffectConfigError) -> None:
    """Check one effect's block (``None`` = its defaults) against ``cls``'s declarations for ``n`` joints."""
    if block is None:
        return
    if not isinstance(block, dict):
        raise error(f"{where}: an effect's block must be a mapping of its fields, got {block!r}")
    check_keys(block, effect_yaml_keys(cls), where, error)
    for key, value in block.items():
        per_joint(value, n, join_key(where, key), error)


def check_effects_block(config: Any, n: int, where: str, error: type[Exception] = EffectConfigError) -> None:
    """Check an ``effects:`` mapping ``{name: block}`` for ``n`` joints, whole before the first plugin is imported:
    each name is a library effect (else the nearest is named) or a plugin path the user consented to, then each
    block fits its class (:func:`check_effect_block`)."""
    if config is None:
        return
    if not isinstance(config, dict):
        raise error(f"{where}: effects must be a mapping {{name: parameters}}, got {config!r}")
    for name in config:
        key = join_key(where, str(name))
        if not is_plugin_path(str(name)) and name not in EFFECTS:
            hint = " (the payload has its own top-level 'payload' block)" if name == "payload" else ""
            raise error(f"{key}: unknown joint effect {str(name)!r}{hint}{nearest_hint(str(name), EFFECTS)} or a "
                        "plugin 'package.module:Class'")
        if is_plugin_path(str(name)):
            try:
                check_consent(str(name))
            except EffectConfigError as exc:
                raise error(f"{key}: {exc}") from exc
    for name, block in config.items():
        key = join_key(where, str(name))
        try:
            cls = resolve_effect(str(name))
        except EffectConfigError as exc:
            raise error(f"{key}: {exc}") from exc
        check_effect_block(cls, block, n, key, error)


def make_effects(config: dict | None, n: int, where: str = "effects",
                 error: type[Exception] = EffectConfigError) -> list[JointEffect]:
    """Build the effects of a YAML ``effects:`` mapping ``{name: block}`` for ``n`` joints — library effects in
    registry order, then plugins in the mapping's order — after checking it once (:func:`check_effects_block`, its
    errors as ``error`` naming ``where``). A range a class refuses is its :class:`EffectConfigError` naming the
    field; two plugins of the same effect name are refused."""
    check_effects_block(config, n, where, error)
    config = config or {}
    library = [_build(name, cls, config[name], n) for name, cls in EFFECTS.items() if name in config]
    plugins = {str(p): resolve_effect(str(p)) for p in config if is_plugin_path(str(p))}
    names = [cls.name for cls in plugins.values()]
    twice = sorted({k for k in names if names.count(k) > 1})
    if twice:
        raise error(f"{where}: plugins {sorted(plugins)}: effect name(s) {twice} given more than once")
    return library + [_build(p, cls, config[p], n) for p, cls in plugins.items()]


def _build(key: str, cls: type[JointEffect], block: Any, n: int) -> JointEffect:
    """``cls.from_config(block, n)``; a block or a plugin class that cannot make an instance names ``key``."""
    try:
        return cls.from_config(block, n)
    except TypeError as exc:        # e.g. a plugin that does not implement torque(), a field the class lacks
        raise EffectConfigError(f"{key}: {exc}") from None
