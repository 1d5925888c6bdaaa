"""The sections of a training config (``model:``, ``data:``, ``train:`` of a ``train_*.yaml``) as dataclasses."""
from __future__ import annotations

from dataclasses import fields
from typing import Any, TypeVar

__all__ = ["section_from_dict"]

T = TypeVar("T")


def section_from_dict(cls: type[T], d: dict[str, Any] | None, section: str) -> T:
    """``cls(**d)`` for the dataclass ``cls`` of config section ``section``; a key that is not one of its fields
    raises ``ValueError`` naming the section, the keys and the allowed ones. ``None`` gives the defaults."""
    d = dict(d or {})
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(f"{section}: unknown key(s) {unknown}; allowed: {sorted(known)}")
    return cls(**d)
