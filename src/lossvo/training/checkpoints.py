"""Checkpoints of a fit: written atomically, checked before a resume (contents: docs/training.md)."""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from typing import Any

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO

from lossvo.atomic import atomic_path
from lossvo.evaluation.checkpoints import TRAINED_WITH, CheckpointError, Description, lookup, read
from lossvo.training.module import VOModule


def check_resume(path: str | os.PathLike, module: VOModule, data: Mapping[str, Any]) -> tuple[int, int]:
    """Refuse to resume from a checkpoint of another loss, network (shape) or training data setting, naming
    the difference; returns the checkpoint's epoch (0-based) and global step."""
    content = read(path)
    described = Description.of(content)
    theirs, ours = described.loss.get("_target_"), module.hparams["loss"].get("_target_")
    if theirs != ours:
        raise CheckpointError(f"{path}: trained with loss {theirs}, this run has loss {ours}: resume with "
                              f"the same loss, or start a new run")  # fmt: skip
    theirs, ours = described.model.get("_target_"), module.hparams["model"].get("_target_")
    if theirs != ours:
        raise CheckpointError(f"{path}: its network is {theirs}, this run's is {ours}")
    _check_shapes(path, content["state_dict"], module.state_dict())
    recorded = described.data or {}
    for key in TRAINED_WITH:
        theirs, ours = lookup(recorded, key), lookup(data, key)
        if theirs is not None and theirs != ours:
            raise CheckpointError(
                f"{path}: trained with data.{key}={theirs!r}, this run has data.{key}={ours!r}"
            )
    return described.epoch, described.global_step


def _check_shapes(path: str | os.PathLike, saved: Mapping[str, Any], current: Mapping[str, Any]) -> None:
    """One line naming the first parameter that is missing, extra or of another shape."""
    missing, extra = sorted(current.keys() - saved.keys()), sorted(saved.keys() - current.keys())
    if missing:
        raise CheckpointError(f"{path}: has no {missing[0]} (this run's network has one of shape "
                              f"{tuple(current[missing[0]].shape)})")  # fmt: skip
    if extra:
        raise CheckpointError(f"{path}: has {extra[0]}, which this run's network lacks")
    for name in sorted(current):
        theirs, ours = tuple(saved[name].shape), tuple(current[name].shape)
        if theirs != ours:
            raise CheckpointError(f"{path}: {name} has shape {theirs}, this run's network {ours}")


class AtomicCheckpointIO(TorchCheckpointIO):
    """Checkpoints written next to their path and renamed onto it (Lightning's save copies across disks)."""

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: str | os.PathLike, storage_options: Any | None = None
    ) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options, got {storage_options!r}")
        buffer = io.BytesIO()  # serialised first: a full disk then fails in write_bytes with its OSError,
        torch.save(checkpoint, buffer)  # not deep inside torch's zip writer as a RuntimeError
        with atomic_path(path, suffix=".ckpt") as tmp:
            tmp.write_bytes(buffer.getbuffer())
