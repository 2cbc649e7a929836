"""Tables of named things (the realism axes, the profile axes, the sweep's configurations):
one rule for building them, so a repeated name is an error instead of a silent overwrite."""

from __future__ import annotations

from typing import Protocol, TypeVar

__all__ = ["by_name"]


class _Named(Protocol):
    @property
    def name(self) -> str: ...


T = TypeVar("T", bound=_Named)


def by_name(*items: T) -> dict[str, T]:
    """``{item.name: item}`` in the order given; a name given twice is a ``ValueError`` naming
    it (a dict comprehension would keep the last one and drop the first without a word)."""
    out: dict[str, T] = {}
    for item in items:
        if item.name in out:
            raise ValueError(f"the name {item.name!r} is given twice")
        out[item.name] = item
    return out
