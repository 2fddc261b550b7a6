"""Checkpoints as the contract between training and everything after it.

A lossvo checkpoint is a Lightning checkpoint of :class:`lossvo.training.module.VOModule` that holds only
primitives (it loads with torch's default ``weights_only``):

- ``hyper_parameters``: the network, loss, optimiser and scheduler configs the module was built from;
- ``state_dict``: the weights;
- ``data``: :meth:`lossvo.data.datamodules.KittiDataModule.description` of the training data: the
  datamodule's ``_target_`` and arguments (frame size, ``seq_len``, splits, normalisation mode ...),
  ``dataset_root`` and the normalisation ``statistics`` the network was trained with.

This module reads them (one line naming the file when a file is not one), builds the data config that
evaluates a checkpoint (:func:`evaluation_data`) and checks that a checkpoint can resume a run
(:func:`check_resume`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO

from lossvo.atomic import atomic_path
from lossvo.training.module import VOModule

TRAINED_WITH = ("height", "width", "seq_len", "normalization")
"""Data settings a trained network depends on: evaluation takes them from its checkpoint."""

RECORD_ONLY = ("statistics", "dataset_root")
"""Entries of a checkpoint's ``data`` that describe the training data but are not datamodule arguments."""


class CheckpointError(ValueError):
    """A file that is not a usable lossvo checkpoint, or a run that contradicts one; the message is one
    line naming the file or the key."""


def read(path: str | os.PathLike) -> dict[str, Any]:
    """The content of a lossvo checkpoint, loaded on the CPU with ``weights_only``.

    Raises:
        CheckpointError: no such file, or not a (complete) lossvo checkpoint.
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        content = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a truncated or foreign file: one line naming it, not torch's traceback
        raise CheckpointError(f"{path}: cannot load as a lossvo checkpoint ({type(e).__name__}: "
                              f"{_first_line(e)})") from None  # fmt: skip
    hparams = content.get("hyper_parameters") if isinstance(content, dict) else None
    complete = isinstance(hparams, dict) and {"model", "loss"} <= hparams.keys() and "state_dict" in content
    if not complete:
        raise CheckpointError(f"{path}: cannot load as a lossvo checkpoint (no lossvo network, loss and "
                              f"weights in it)")  # fmt: skip
    return content


def load_module(path: str | os.PathLike, device: str | torch.device = "cpu") -> VOModule:
    """The :class:`VOModule` of a checkpoint on ``device``, with its training data's description in
    ``module.data`` (None for a checkpoint that records none)."""
    read(path)  # one clear line for a missing or foreign file
    try:
        return VOModule.load_from_checkpoint(Path(path), map_location=torch.device(device), weights_only=True)
    except Exception as e:  # e.g. a loss or network class that no longer exists
        raise CheckpointError(f"{path}: cannot rebuild its network ({type(e).__name__}: "
                              f"{_first_line(e)})") from None  # fmt: skip


def recorded_data(path: str | os.PathLike, module: VOModule) -> dict[str, Any]:
    """The checkpoint's description of its training data; an error naming the file when it has none."""
    if not isinstance(module.data, dict) or not module.data.get("statistics"):
        raise CheckpointError(f"{path}: the checkpoint records no data settings (frame size, seq_len, "
                              f"normalisation statistics) to evaluate it with")  # fmt: skip
    return module.data


def evaluation_data(
    recorded: Mapping[str, Any], selected: Mapping[str, Any] | None, explicit: Mapping[str, Any]
) -> dict[str, Any]:
    """The data config that evaluates a checkpoint.

    Args:
        recorded: the checkpoint's ``data`` (:func:`recorded_data`).
        selected: the composed data config when another dataset was chosen (``data=kitti``), else None:
            the recorded one is used.
        explicit: the ``data.KEY=VALUE`` overrides given on the command line, by key.
    Returns:
        A datamodule config: the chosen (or recorded) one with the explicit overrides, the frame size,
        ``seq_len`` and normalisation of the checkpoint, its ``statistics``, and no training or
        validation sequences (the data need not hold any).
    Raises:
        CheckpointError: an explicit override contradicts what the network was trained with.
    """
    for key in TRAINED_WITH:
        if key in explicit and explicit[key] != recorded.get(key):
            raise CheckpointError(
                f"data.{key}={explicit[key]!r} contradicts the checkpoint, whose network was trained with "
                f"data.{key}={recorded.get(key)!r}: drop the override"
            )
    base = dict(selected) if selected is not None else {
        k: v for k, v in recorded.items() if k not in RECORD_ONLY
    }  # fmt: skip
    base.update(explicit)
    base.update({key: recorded[key] for key in TRAINED_WITH if key in recorded})
    return {**base, "train": [], "val": [], "statistics": recorded["statistics"]}


def check_resume(path: str | os.PathLike, module: VOModule, data: Mapping[str, Any]) -> tuple[int, int]:
    """Refuse to resume a run from a checkpoint of another loss, parameterisation, network shape or
    training data setting, naming the difference; returns the checkpoint's epoch (0-based) and global
    step.

    Args:
        path: the checkpoint. module: the run's freshly built module. data: the run's data description.
    """
    content = read(path)
    hparams = content["hyper_parameters"]
    theirs, ours = hparams["loss"].get("_target_"), module.hparams["loss"].get("_target_")
    if theirs != ours:
        raise CheckpointError(f"{path}: trained with loss {theirs}, this run has loss {ours}: resume with "
                              f"the same loss, or start a new run")  # fmt: skip
    theirs, ours = hparams["model"].get("_target_"), module.hparams["model"].get("_target_")
    if theirs != ours:
        raise CheckpointError(f"{path}: its network is {theirs}, this run's is {ours}")
    _check_shapes(path, content["state_dict"], module.state_dict())
    recorded = content.get("data") or {}
    for key in TRAINED_WITH:
        if key in recorded and recorded[key] != data.get(key):
            raise CheckpointError(f"{path}: trained with data.{key}={recorded[key]!r}, this run has "
                                  f"data.{key}={data.get(key)!r}")  # fmt: skip
    return int(content.get("epoch", 0)), int(content.get("global_step", 0))


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


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else ""


class AtomicCheckpointIO(TorchCheckpointIO):
    """Checkpoints written to a temporary file next to their path and renamed onto it, so a crash or a
    full disk leaves the previous checkpoint in place. Lightning's own save stages the file in the
    system's temporary folder and moves it, which is a copy, not atomic, when that is another disk."""

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: str | os.PathLike, storage_options: Any | None = None
    ) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options, got {storage_options!r}")
        with atomic_path(path, suffix=".ckpt") as tmp:
            torch.save(checkpoint, tmp)
