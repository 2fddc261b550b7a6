"""The arguments a network's config gives, checked: one ``UserError`` naming ``model.<key>`` for a bad value;
and the two steps both networks take while they build: the seeded build and the memory layout."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import torch
from torch import Tensor

from lossvo.checks import is_integer, is_number
from lossvo.console import UserError


def head_bias(value: object, out_dim: int) -> Tensor:
    if value is None:
        return torch.zeros(out_dim)
    try:
        numbers = [float(v) for v in value] if isinstance(value, Iterable) else []
        bias = torch.as_tensor(numbers, dtype=torch.float32)
    except (TypeError, ValueError):
        bias = torch.empty(0)
    if bias.shape != (out_dim,) or not torch.isfinite(bias).all():
        raise UserError(f"model.head_bias: expected null or {out_dim} finite numbers, got {value!r}")
    return bias


def check_int(name: str, value: object, minimum: int, why: str = "") -> int:
    if not is_integer(value, minimum):
        raise UserError(f"model.{name}: expected an integer >= {minimum}{why}, got {value!r}")
    return value


def check_float(name: str, value: object, low: float, high: float, high_open: bool, what: str) -> float:
    if (
        is_number(value)
        and math.isfinite(value)
        and (low <= value < high if high_open else low < value <= high)
    ):
        return float(value)
    raise UserError(f"model.{name}: expected {what}, got {value!r}")


def dropout(name: str, value: object) -> float:
    return check_float(name, value, 0.0, 1.0, True, "a probability in [0, 1)")


def memory_format(channels_last: object) -> torch.memory_format:
    """``model.channels_last``: channels-last (NHWC) or the contiguous layout."""
    if not isinstance(channels_last, bool):
        raise UserError(f"model.channels_last: expected true or false, got {channels_last!r}")
    return torch.channels_last if channels_last else torch.contiguous_format


def seeded_build(build: Callable[[], None]) -> int:
    """Create a network's layers with ``build`` outside the caller's random stream (their default
    initialisation is overwritten) and return the one number drawn from that stream: the init seed."""
    init_seed = int(torch.randint(0, 2**62, ()))
    with torch.random.fork_rng(devices=[]):
        build()
    return init_seed
