"""FlowNetS weights (FlowNetPytorch's ``flownets_bn_*.pth.tar``) into DeepVO's encoder, by name and with
a shape check: every tensor loaded, missing, unexpected or of another shape is reported (:class:`LoadReport`)
and warned about; nothing is downloaded. The encoder's names follow FlowNetPytorch's (see
:mod:`lossvo.models.deepvo`); FlowNetS expects ``img / 255 - 0.5`` input (``normalization: flownet``).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor, nn

from lossvo.console import UserError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoadReport:
    """What :func:`load_flownet` did, by state-dict key (without the ``encoder.`` prefix).

    ``missing``: encoder keys the file lacks (``num_batches_tracked`` counters are not listed);
    ``unexpected``: file keys the encoder lacks (the FlowNetS decoder, or other architectures' convs);
    ``mismatched``: (key, shape in the file, shape in the encoder) -- same name, different shape, not loaded.
    """

    loaded: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    unexpected: list[str] = field(default_factory=list)
    mismatched: list[tuple[str, tuple[int, ...], tuple[int, ...]]] = field(default_factory=list)

    def summary(self) -> str:
        return (
            f"{len(self.loaded)} loaded, {len(self.missing)} missing, {len(self.unexpected)} unexpected, "
            f"{len(self.mismatched)} mismatched"
        )


def _read_state_dict(path: Path) -> dict[str, Tensor]:
    if path.is_dir():
        raise UserError(f"FlowNet checkpoint {path} is a folder, expected a file")
    if not path.is_file():
        raise FileNotFoundError(f"FlowNet checkpoint not found: {path}")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise UserError(
            f"FlowNet checkpoint {path} could not be loaded with torch.load(weights_only=True): {e}"
        ) from e
    if isinstance(obj, dict) and isinstance(obj.get("state_dict"), dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict) or not obj or not all(isinstance(v, Tensor) for v in obj.values()):
        raise UserError(
            f"FlowNet checkpoint {path} holds no state dict (expected a dict with key 'state_dict' or a "
            f"bare name -> tensor dict), got {type(obj).__name__}"
        )
    prefix = "module."  # saved from DataParallel
    if all(k.startswith(prefix) for k in obj):
        obj = {k[len(prefix) :]: v for k, v in obj.items()}
    return obj


@torch.no_grad()
def load_flownet(model: nn.Module, path: str | Path) -> LoadReport:
    """Initialise ``model.encoder`` (a :class:`lossvo.models.deepvo.DeepVO`'s) from a FlowNetPytorch
    FlowNetS checkpoint, by name with shape checks.

    The file is ``torch.save({'epoch', 'arch', 'state_dict', 'div_flow', ...})`` as FlowNetPytorch writes
    it (``flownets_bn_EPE2.459.pth.tar`` for ``batch_norm=True``), or a bare state dict. Keys are
    ``conv1.0.weight``, ``conv1.1.{weight,bias,running_mean,running_var}``, ... ``conv6.*``; the decoder
    (``deconv*``, ``predict_flow*``, ``upsampled_flow*``) is reported as unexpected. A tensor whose shape
    differs is skipped with a warning. The weights expect inputs ``img / 255 - 0.5``
    (``normalization: flownet``).

    Raises:
        FileNotFoundError: no file at ``path``.
        UserError: the file cannot be read with ``weights_only=True``, holds no state dict, or no tensor
            matches the encoder (by name and shape).
    """
    path = Path(path)
    source = _read_state_dict(path)
    encoder = model.get_submodule("encoder")
    target = encoder.state_dict()
    loaded: list[str] = []
    mismatched: list[tuple[str, tuple[int, ...], tuple[int, ...]]] = []
    for key, value in source.items():
        if key not in target:
            continue
        if value.shape != target[key].shape:
            mismatched.append((key, tuple(value.shape), tuple(target[key].shape)))
            continue
        loaded.append(key)
    missing = [k for k in target if k not in source and not k.endswith("num_batches_tracked")]
    unexpected = [k for k in source if k not in target]
    report = LoadReport(loaded=loaded, missing=missing, unexpected=unexpected, mismatched=mismatched)

    if not any(not k.endswith("num_batches_tracked") for k in loaded):  # a counter is not a match
        if mismatched:
            raise UserError(
                f"FlowNet checkpoint {path}: nothing matches the encoder -- all {len(mismatched)} tensors "
                f"with matching names have different shapes (e.g. {mismatched[0][0]}: file "
                f"{mismatched[0][1]} vs model {mismatched[0][2]}); FlowNetS weights need width_mult=1 "
                f"(model has width_mult={model.width_mult:g})"
            )
        raise UserError(
            f"FlowNet checkpoint {path}: nothing matches the encoder -- none of its {len(source)} keys "
            f"(e.g. {next(iter(source))!r}) is an encoder key such as 'conv1.0.weight'"
        )
    for key in loaded:
        target[key].copy_(source[key])  # state_dict tensors share storage with the parameters
    if mismatched:
        details = "; ".join(f"{k}: file {a} vs model {b}" for k, a, b in mismatched)
        warnings.warn(
            f"FlowNet checkpoint {path}: {len(mismatched)} tensor(s) with a different shape were not "
            f"loaded: {details}",
            stacklevel=2,
        )
    if missing:
        log.warning("FlowNet checkpoint %s lacks %d encoder tensor(s): %s", path, len(missing), missing)
    return report
