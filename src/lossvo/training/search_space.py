"""A hyperparameter search space written in Hydra's sweep syntax, as Optuna distributions: ``choice``,
``interval`` (``tag(log, ...)``: log scale), ``range`` (inclusive) and ``shuffle(range)`` (categories); any
other override is fixed. The table: docs/sweep.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, Override, RangeSweep, Transformer
from hydra.errors import HydraException
from optuna.distributions import (
    BaseDistribution,
    CategoricalDistribution,
    FloatDistribution,
    IntDistribution,
)

from lossvo.console import UserError, first_line

CHOICE_TYPES = (str, int, float, bool, type(None))
"""The types a ``choice`` may hold (Optuna's categories)."""


def distribution_of(override: Override) -> BaseDistribution | str:
    """The distribution of a sweep override, or a plain override's value as written; UserError naming the
    key of a sweep no search space holds."""
    key = override.get_key_element()
    if not override.is_sweep_override():
        return str(override.get_value_element_as_str())
    value = override.value()
    try:
        if isinstance(value, ChoiceSweep):
            return CategoricalDistribution(_choices(override))
        if isinstance(value, RangeSweep) and value.shuffle:  # Hydra shuffles: sorted, one search space
            return CategoricalDistribution(sorted(_choices(override)))
        if isinstance(value, RangeSweep):
            return _range(value)
        if isinstance(value, IntervalSweep):
            return _interval(value)
    except (UserError, ValueError) as e:  # ValueError: a number Hydra's sweep holds that float() refuses
        raise UserError(f"{key}: {first_line(e)} (in {override.input_line})") from e
    expected = "choice(...), interval(low, high), tag(log, interval(low, high)) or range(start, stop, step)"
    raise UserError(f"{key}: {override.input_line} is not a search space (expected {expected})")


def _choices(override: Override) -> list[Any]:
    """A choice sweep's values as Optuna categories (Hydra's encoding of each element)."""
    choices = list(override.sweep_iterator(transformer=Transformer.encode))
    wrong = [c for c in choices if not isinstance(c, CHOICE_TYPES)]
    if wrong:
        raise UserError(f"a choice holds str, int, float, bool or null, not {wrong[0]!r}")
    return choices


def _range(value: RangeSweep) -> BaseDistribution:
    """``range(start, stop, step)``: ``start`` to ``stop`` inclusive in steps of ``step``."""
    if value.start is None or value.stop is None:
        raise UserError("a range needs a start and a stop")
    if any(isinstance(v, float) for v in (value.start, value.stop, value.step)):
        return FloatDistribution(float(value.start), float(value.stop), step=float(value.step))
    return IntDistribution(int(value.start), int(value.stop), step=int(value.step))


def _interval(value: IntervalSweep) -> BaseDistribution:
    """``interval(low, high)``, on a log scale where tagged ``log``."""
    if value.start is None or value.end is None:
        raise UserError("an interval needs a low and a high end")
    return FloatDistribution(float(value.start), float(value.end), log="log" in value.tags)


def _parse_error(error: HydraException) -> str:
    """The line of Hydra's parse error that says what is wrong (not its heading or link)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    said = [line for line in lines if not line.startswith(("Error parsing override", "See https://"))]
    return (said or lines or [type(error).__name__])[0]


def parse(overrides: Sequence[str]) -> tuple[dict[str, BaseDistribution], dict[str, str]]:
    """The search space (key -> distribution) and fixed overrides (key -> value as written) of overrides,
    a key given twice at its last value; UserError (one line) naming the key of a bad one."""
    parser = OverridesParser.create()
    space: dict[str, BaseDistribution] = {}
    fixed: dict[str, str] = {}
    for line in overrides:
        try:
            (override,) = parser.parse_overrides([line])
        except HydraException as e:
            raise UserError(f"{line.split('=', 1)[0]}: {_parse_error(e)} (in {line})") from e
        key = override.get_key_element()
        space.pop(key, None)
        fixed.pop(key, None)
        found = distribution_of(override)
        if isinstance(found, BaseDistribution):
            space[key] = found
        else:
            fixed[key] = found
    return space, fixed
