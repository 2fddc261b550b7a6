"""The training step's tensors: its losses as one (optionally compiled) function, the epoch's record kept on
the training device (no host synchronisation per step) and the optimiser's kernel choice. Why: docs/gpu.md.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor

from lossvo.console import UserError

COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
AUTO_CUDA_MODE = "reduce-overhead"
"""What ``compile=auto`` compiles with on a CUDA device (elsewhere it runs eagerly)."""


def compile_mode(setting: bool | str | None, device: torch.device) -> str | None:
    """The ``torch.compile`` mode of the training losses on ``device`` for the ``compile`` setting, or
    None for eager (``auto`` is eager on a CPU: compiling costs more than it saves in a sweep's jobs)."""
    check_compile(setting)
    if setting == "auto":
        return AUTO_CUDA_MODE if device.type == "cuda" else None
    return "default" if setting is True else (str(setting) if setting else None)


def check_compile(setting: Any) -> None:
    """UserError naming ``compile`` unless the setting is one :func:`compile_mode` takes."""
    if setting is None or isinstance(setting, bool) or setting == "auto" or setting in COMPILE_MODES:
        return
    expected = ", ".join(("true", "false", "auto", *COMPILE_MODES))
    raise UserError(f"compile: expected one of {expected}, got {setting!r}")


def compiled(function: Callable[..., Any], mode: str | None) -> Callable[..., Any]:
    """``function`` compiled in ``mode`` (static shapes), or itself for None."""
    if mode is None:
        return function
    return torch.compile(function, mode=mode, dynamic=False)


def optimizer_options(factory: Callable[..., Any], device: torch.device, config: Mapping[str, Any]) -> dict:
    """Keyword arguments picking an optimiser's fastest kernels where its ``config`` chooses none: ``fused``
    on CUDA, ``foreach`` elsewhere (on a CPU it gives the per-parameter loop's numbers, ``fused`` not)."""
    if "fused" in config or "foreach" in config:
        return {}
    target = getattr(factory, "func", factory)  # a functools.partial's class
    try:
        accepted = inspect.signature(target).parameters
    except (TypeError, ValueError):
        return {}
    if device.type == "cuda" and "fused" in accepted:
        return {"fused": True}
    if "foreach" in accepted:
        return {"foreach": True}
    return {}


class StepRecord:
    """Each training step's loss terms, written on the device and copied to the host once an epoch. A row:
    the loss's scalars in :attr:`keys` order, whether the output was finite (1.0 or 0.0), the frame pairs."""

    def __init__(self, capacity: int, keys: tuple[str, ...], device: torch.device) -> None:
        self.keys = keys
        self.table = torch.zeros(max(capacity, 1), len(keys) + 2, dtype=torch.float32, device=device)
        self.count = torch.zeros((), dtype=torch.int64, device=device)
        self.steps = 0  # host-side count of the rows written

    def write(self, row: Tensor) -> None:
        """Append a row (len(keys) + 2,) float32; the table grows when full."""
        if self.steps == len(self.table):  # more batches than announced: double (one allocation)
            self.table = torch.cat((self.table, torch.zeros_like(self.table)))
        self.table.index_copy_(0, self.count.view(1), row.view(1, -1))
        self.count.add_(1)
        self.steps += 1

    def rows(self) -> np.ndarray:
        """(steps, len(keys) + 2) float32: every row written (one copy to the host)."""
        return self.table[: self.steps].cpu().numpy()


def step_row(out: Mapping[str, Tensor], pred: Tensor, pairs: int) -> Tensor:
    """A step's record row (len(out) + 2,) float32, without gradient (see :class:`StepRecord`)."""
    with torch.no_grad():
        finite = torch.isfinite(pred).all().to(torch.float32)
        values = [value.detach().to(torch.float32) for value in out.values()]
        return torch.stack([*values, finite, torch.full_like(finite, float(pairs))])


def epoch_means(rows: np.ndarray, width: int) -> np.ndarray:
    """(width,) float32 means over an epoch's record ``rows``, weighted by frame pairs, accumulated in
    float32 step by step as Lightning's epoch reduction does (so the numbers equal per-step logging's)."""
    total = np.zeros(width, dtype=np.float32)
    pairs = 0
    for row in rows:  # in step order: float32 sums depend on it (a few hundred rows, once an epoch)
        weight = int(row[-1])
        total = total + row[:width] * np.float32(weight)
        pairs += weight
    return total / np.float32(max(pairs, 1))


def first_non_finite(rows: np.ndarray) -> int | None:
    """The index of the first row whose loss (column 0) is not finite, or None."""
    bad = np.flatnonzero(~np.isfinite(rows[:, 0]))
    return int(bad[0]) if len(bad) else None
