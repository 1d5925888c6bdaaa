"""The sections of a training config (``model:``, ``data:``, ``train:`` of a ``train_*.yaml``) as dataclasses."""
from __future__ import annotations

from typing import Any, TypeVar

from proprio.typed_yaml import load_typed

__all__ = ["section_from_dict"]

T = TypeVar("T")


def section_from_dict(cls: type[T], d: dict[str, Any] | None, section: str) -> T:
    """The dataclass ``cls`` of config section ``section`` built strictly from ``d``
    (:func:`proprio.typed_yaml.load_typed`): an unknown key raises ``ValueError`` naming the section, the key and the
    nearest allowed one; a value of the wrong type names the field. ``None`` gives the defaults."""
    return load_typed(cls, d, section)
