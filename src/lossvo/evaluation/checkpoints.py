"""lossvo checkpoints, read and written here only: a Lightning checkpoint of primitives (``weights_only``)
holding the weights and the :class:`Description` of how they were trained. :func:`load_network` rebuilds
the network from it alone; :func:`evaluation_data` builds the data config that evaluates it.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from hydra.utils import instantiate
from torch import Tensor, nn

from lossvo import models
from lossvo.checks import is_integer
from lossvo.console import UserError, first_line
from lossvo.losses import PoseLoss

TRAINED_WITH = (
    "frames.height",
    "frames.width",
    "windows.seq_len",
    "frames.normalization",
    "flow.method",
    "flow.scale",
)
"""Data settings a trained network depends on: evaluation takes them from its checkpoint."""

SCHEMA_VERSION = 2
"""The version of a lossvo checkpoint's own entries and of its ``data`` description."""

RECORD_ONLY = ("statistics", "dataset_root", "intrinsics")
"""Entries of a checkpoint's ``data`` that are not datamodule arguments."""


class CheckpointError(UserError):
    """A file that is not a usable lossvo checkpoint, or a run that contradicts one; the message is one
    line naming the file or the key."""


@dataclass(frozen=True)
class Description:
    """How a checkpoint's network was trained: the ``model`` and ``loss`` configs, the training ``data``'s
    :meth:`lossvo.data.datamodules.VODataModule.description` (an earlier version's upgraded; None where
    none was recorded), the CPU ``threads`` (None: not recorded), the ``epoch`` (from 0) and step."""

    model: dict[str, Any]
    loss: dict[str, Any]
    data: dict[str, Any] | None = None
    threads: int | None = None
    epoch: int = 0
    global_step: int = 0

    @classmethod
    def of(cls, content: Mapping[str, Any]) -> Description:
        """The description in a checkpoint's content (:func:`read`)."""
        hparams, threads, data = content["hyper_parameters"], content.get("threads"), content.get("data")
        return cls(dict(hparams["model"]), hparams["loss"], data if isinstance(data, dict) else None,
                   threads if is_integer(threads) else None, int(content.get("epoch", 0)),
                   int(content.get("global_step", 0)))  # fmt: skip


def describe(checkpoint: dict[str, Any], data: dict[str, Any] | None) -> None:
    """Record the training ``data`` (where known), the thread count and :data:`SCHEMA_VERSION` in a
    checkpoint being saved (Lightning records the rest of its :class:`Description`)."""
    checkpoint["schema_version"] = SCHEMA_VERSION
    if data is not None:
        checkpoint["data"] = data
    checkpoint["threads"] = torch.get_num_threads()


class TrainedNetwork(nn.Module):
    """A network, the :class:`lossvo.losses.PoseLoss` that decodes its outputs, and the checkpoint's
    ``data`` and ``threads`` (each None where not recorded)."""

    def __init__(self, model: nn.Module, loss: PoseLoss, data: dict[str, Any] | None = None,
                 threads: int | None = None) -> None:  # fmt: skip
        super().__init__()
        self.model, self.loss = model, loss
        self.data, self.threads = data, threads

    def forward(self, batch: Mapping[str, Tensor]) -> Tensor:
        """Network outputs (B, L-1, dim) for a batch of windows (:func:`lossvo.models.apply`)."""
        return models.apply(self.model, batch)

    def decode(self, pred: Tensor) -> Tensor:
        """Relative poses (..., 4, 4) from network outputs (..., dim)."""
        return self.loss.decode(pred)


def read(path: str | os.PathLike) -> dict[str, Any]:
    """The content of a lossvo checkpoint, loaded on the CPU with ``weights_only``; CheckpointError, one
    line, for a file that is not one of :data:`SCHEMA_VERSION`."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        content = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a truncated or foreign file: one line naming it, not torch's traceback
        with path.open("rb") as f:
            torch_file = f.read(4).startswith((b"PK\x03\x04", b"\x80"))  # torch.save's zip, or a pickle
        reason = f"{type(e).__name__}: {first_line(e)}" if torch_file else "not a file written by torch.save"
        raise CheckpointError(f"{path}: cannot load as a lossvo checkpoint ({reason})") from None
    hparams = content.get("hyper_parameters") if isinstance(content, dict) else None
    complete = isinstance(hparams, dict) and {"model", "loss"} <= hparams.keys() and "state_dict" in content
    if not complete:
        raise CheckpointError(f"{path}: cannot load as a lossvo checkpoint (no lossvo network, loss and "
                              f"weights in it)")  # fmt: skip
    version = content.get("schema_version")
    if version != SCHEMA_VERSION:
        found = f"schema_version {version!r} is not supported" if version else "without schema_version"
        raise CheckpointError(f"{path}: checkpoint {found} (supported: {SCHEMA_VERSION}); train the network "
                              "again with this version")  # fmt: skip
    return content


def load_network(path: str | os.PathLike, device: str | torch.device = "cpu") -> TrainedNetwork:
    """The network of a checkpoint, with its loss and its training record, on ``device``."""
    content = read(path)
    described = Description.of(content)
    try:
        network = TrainedNetwork(instantiate(described.model), instantiate(described.loss),
                                 described.data, described.threads)  # fmt: skip
        network.load_state_dict(content["state_dict"])
    except Exception as e:  # e.g. a loss or network class that no longer exists
        raise CheckpointError(f"{path}: cannot rebuild its network ({type(e).__name__}: "
                              f"{first_line(e)})") from None  # fmt: skip
    return network.to(torch.device(device))


def recorded_data(path: str | os.PathLike, network: TrainedNetwork) -> dict[str, Any]:
    """The checkpoint's description of its training data; an error naming the file when it has none."""
    if not isinstance(network.data, dict) or not network.data.get("statistics"):
        raise CheckpointError(f"{path}: the checkpoint records no data settings (frame size, seq_len, "
                              f"normalisation statistics) to evaluate it with")  # fmt: skip
    return network.data


def lookup(data: Mapping[str, Any], path: str) -> Any:
    """The entry at a dotted ``path`` of a data config (``frames.height``), or None."""
    for part in path.split("."):
        if not isinstance(data, Mapping):
            return None
        data = data.get(part)  # type: ignore[assignment]
    return data


def _with(data: Mapping[str, Any], path: str, value: Any) -> dict[str, Any]:
    """A copy of ``data`` with ``value`` at the dotted ``path`` (the mappings on the way copied or made)."""
    head, _, rest = path.partition(".")
    out = dict(data)
    inner = out.get(head)
    out[head] = _with(inner if isinstance(inner, Mapping) else {}, rest, value) if rest else value
    return out


def evaluation_data(
    recorded: Mapping[str, Any], selected: Mapping[str, Any] | None, explicit: Mapping[str, Any]
) -> dict[str, Any]:
    """The data config that evaluates a checkpoint: the ``selected`` one (None: the ``recorded`` one) with
    the command line's ``explicit`` overrides by dotted key, the settings :data:`TRAINED_WITH` and the
    statistics recorded, and no training or validation sequences; CheckpointError for an override that
    contradicts the recorded settings."""
    for key in TRAINED_WITH:
        if key in explicit and explicit[key] != lookup(recorded, key):
            raise CheckpointError(
                f"data.{key}={explicit[key]!r} contradicts the checkpoint, whose network was trained with "
                f"data.{key}={lookup(recorded, key)!r}: drop the override"
            )
    base = dict(selected) if selected is not None else {
        k: v for k, v in recorded.items() if k not in RECORD_ONLY
    }  # fmt: skip
    trained = {key: lookup(recorded, key) for key in TRAINED_WITH if lookup(recorded, key) is not None}
    fixed = trained | {"splits.train": [], "splits.val": [], "frames.statistics": recorded["statistics"]}
    for key, value in [*explicit.items(), *fixed.items()]:
        base = _with(base, key, value)
    return base
