"""Type tests of config and file values that, unlike ``isinstance(value, int)``, do not take a ``bool``
(a YAML ``true``) for a number."""

from __future__ import annotations

from typing import TypeGuard


def is_integer(value: object, low: int | None = None) -> TypeGuard[int]:
    """Whether ``value`` is an ``int`` (not a ``bool``) and, given ``low``, ``>= low``."""
    return isinstance(value, int) and not isinstance(value, bool) and (low is None or value >= low)


def is_number(value: object) -> TypeGuard[int | float]:
    """Whether ``value`` is an ``int`` or a ``float`` (not a ``bool``); it may be infinite or NaN."""
    return isinstance(value, int | float) and not isinstance(value, bool)
