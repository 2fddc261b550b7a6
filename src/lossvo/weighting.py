"""How the translation and rotation terms of a pose loss are weighted (config group ``weighting``):
``matched`` (``k = c / small_angle_gain``), ``paper`` (each class's ``paper_k``) or ``learned``
(:class:`HomoscedasticWeighting`). Presets: docs/fair-comparison.md; gains and k per loss: docs/losses.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch
from hydra.utils import get_class
from torch import Tensor, nn

from lossvo.checks import is_number
from lossvo.console import UserError

DEFAULT_C = 100.0
"""The matched preset's small-angle rotation weight: the study's Euler k1, whose gain is 1."""

PRESETS = ("matched", "paper", "learned")


def _check_preset(preset: Any) -> None:
    if preset not in PRESETS:
        raise UserError(f"weighting.preset: expected one of {PRESETS}, got {preset!r}")


def check_c(c: Any) -> float:
    """``weighting.c`` as a float; ``UserError`` for anything but a finite number > 0."""
    if not is_number(c) or not math.isfinite(c) or c <= 0:
        raise UserError(f"weighting.c: expected a finite number > 0, got {c!r}")
    return float(c)


def loss_class(target: str) -> Any:
    """The pose loss class a loss config's ``_target_`` names; ``UserError`` for any other class."""
    cls = get_class(target)
    if not hasattr(cls, "small_angle_gain"):
        raise UserError(f"loss._target_: {target} is not a lossvo pose loss (no small_angle_gain)")
    return cls


def preset_k(target: str, preset: str, c: float = DEFAULT_C, squared: bool = True) -> float | None:
    """The k of a weighting preset for the loss class named ``target``: None for ``learned``, and for an
    unsquared rotation term under ``matched`` (the loss then asks for an explicit k)."""
    _check_preset(preset)
    cls = loss_class(target)
    if preset == "learned":
        return None
    if preset == "paper":
        return float(cls.paper_k)
    return check_c(c) / cls.small_angle_gain if squared else None


def check_k(k: Any, learned: bool) -> None:
    """Refuse an explicit ``loss.k`` together with the learned weighting."""
    if learned and k is not None:
        raise UserError(
            f"loss.k={k!r} cannot be combined with weighting=learned (the learned weights replace k): "
            "drop loss.k, or choose weighting=matched or weighting=paper"
        )


def check_unsquared(squared: Any, k: Any, learned: bool) -> None:
    """Refuse ``loss.squared=false`` with neither ``loss.k`` nor the learned weighting."""
    if squared is False and k is None and not learned:
        raise UserError(
            "loss.squared=false: the unsquared quaternion distance (~ theta / 2) has no matched k; "
            "set loss.k (the study's 14 with weighting=paper) or use weighting=learned"
        )


def check_config(weighting: Mapping[str, Any], loss: Mapping[str, Any]) -> None:
    """Check a job's ``weighting`` and ``loss`` config entries before anything is built (``UserError``)."""
    preset = weighting.get("preset")
    _check_preset(preset)
    if preset == "matched":
        check_c(weighting.get("c"))
        check_unsquared(loss.get("squared"), loss.get("k"), learned=False)
    check_k(loss.get("k"), learned=preset == "learned")


class HomoscedasticWeighting(nn.Module):
    """Learned task weights: ``exp(-s_t) L_t + s_t + exp(-s_r) L_r + s_r`` (Kendall & Cipolla 2017), with
    ``s_t``, ``s_r`` the log-variances (initial values given; float32 parameters in the state dict)."""

    def __init__(self, s_t: float = 0.0, s_r: float = 0.0) -> None:
        super().__init__()
        for name, value in (("s_t", s_t), ("s_r", s_r)):
            if not is_number(value) or not math.isfinite(value):
                raise UserError(f"weighting.learned.{name}: expected a finite number, got {value!r}")
        self.log_vars = nn.Parameter(torch.tensor([float(s_t), float(s_r)]))

    def forward(self, trans_loss: Tensor, rot_loss: Tensor) -> Tensor:
        """Weighted loss (scalar) from the unweighted means of the two terms (scalars)."""
        s = self.log_vars.to(trans_loss.dtype)
        return torch.exp(-s[0]) * trans_loss + s[0] + torch.exp(-s[1]) * rot_loss + s[1]

    def values(self) -> dict[str, Tensor]:
        """The current ``s_t``, ``s_r`` (detached scalars), for logging."""
        s = self.log_vars.detach()
        return {"s_t": s[0], "s_r": s[1]}


def learned_from_config(learned: Mapping[str, Any] | None) -> HomoscedasticWeighting | None:
    """The module for ``weighting.learned`` (a mapping of initial values), or None."""
    if learned is None:
        return None
    if not isinstance(learned, Mapping) or set(learned) - {"s_t", "s_r"}:
        raise UserError(f"weighting.learned: expected a mapping with keys s_t, s_r, got {learned!r}")
    return HomoscedasticWeighting(**{k: learned[k] for k in learned})
