"""Batch transforms, the training augmentations: ``(inputs, targets, generator) -> (inputs, targets)`` on a
batch's device, ``inputs`` holding ``frames`` (B, L, 3, H, W) uint8, ``K`` (B, 3, 3) pixels and optionally
``flow`` (B, L-1, 2, H, W) pixels, ``targets`` (B, L-1, 4, 4) relative poses. Random draws come from
``generator`` (CPU; None: the global one), one a window. docs/data.md has the rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from lossvo.checks import is_number
from lossvo.console import UserError
from lossvo.data import flow as optical_flow
from lossvo.geometry import camera

Inputs = dict[str, torch.Tensor]


def mirror_poses(poses: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) relative poses as the mirrored world shows them: ``S @ T @ S``, S = diag(-1, 1, 1, 1)."""
    sign = torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=poses.dtype).to(poses.device, non_blocking=True)
    return poses * (sign[:, None] * sign)


def mirror_inputs(inputs: Inputs) -> Inputs:
    """Inputs as the mirrored world looks through the mirrored camera: ``frames`` (..., 3, H, W) flipped
    left to right, optionally ``flow`` (..., 2, H, W) and K's principal point mirrored."""
    mirrored = {**inputs, "frames": inputs["frames"].flip(-1)}
    if "flow" in inputs:
        mirrored["flow"] = optical_flow.mirror_flow(inputs["flow"])
    if "K" in inputs:
        mirrored["K"] = camera.mirrored_intrinsics(inputs["K"], inputs["frames"].shape[-1])
    return mirrored


def _where(which: torch.Tensor, new: torch.Tensor, old: torch.Tensor) -> torch.Tensor:
    """``new`` in the selected windows, ``old`` elsewhere; which: (B,) bool on the tensors' device."""
    return torch.where(which.view(-1, *[1] * (old.dim() - 1)), new, old)


def _check(where: str, value: Any, high: float, what: str) -> None:
    if not (is_number(value) and 0.0 <= value <= high):
        raise UserError(f"data.transforms: {where}: expected {what} in [0, {high:g}], got {value!r}")


@dataclass(frozen=True)
class Mirror:
    """Mirror a window left to right with probability ``p`` (:func:`mirror_inputs`, :func:`mirror_poses`)."""

    p: float

    def __post_init__(self) -> None:
        _check("Mirror.p", self.p, 1.0, "a probability")

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        which = (torch.rand(inputs["frames"].shape[0], generator=generator) < self.p).to(targets.device)
        mirrored = mirror_inputs(inputs)
        out = {
            k: _where(which, mirrored[k], v) if k in ("frames", "flow", "K") else v for k, v in inputs.items()
        }
        return out, _where(which, mirror_poses(targets), targets)


@dataclass(frozen=True)
class Roll:
    """Turn the cameras of a window about their optical axes with probability ``p``, each frame after the
    first by its own angle drawn from U[-``max_rad``, ``max_rad``] radians (:func:`rolled_windows`)."""

    p: float
    max_rad: float

    def __post_init__(self) -> None:
        _check("Roll.p", self.p, 1.0, "a probability")
        _check("Roll.max_rad", self.max_rad, 0.5, "radians")

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        B, L = inputs["frames"].shape[:2]
        which = torch.rand(B, generator=generator) < self.p
        draw = (2.0 * torch.rand(B, L - 1, generator=generator) - 1.0) * self.max_rad * which[:, None]
        angles = torch.cat((torch.zeros(B, 1), draw), 1).to(targets.device, non_blocking=True)
        return rolled_windows(inputs, targets, angles)


def roll_poses(poses: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """(B, P, 4, 4) relative poses between cameras each turned about its optical axis by ``angles``
    (B, P + 1) radians: ``Rz(a_k)^T T_k Rz(a_k+1)``."""
    cos, sin = angles.cos(), angles.sin()
    turn = torch.zeros(*angles.shape, 4, 4, dtype=poses.dtype, device=poses.device)
    turn[..., 0, 0], turn[..., 0, 1], turn[..., 1, 0], turn[..., 1, 1] = cos, -sin, sin, cos
    turn[..., 2, 2] = turn[..., 3, 3] = 1.0
    return turn[:, :-1].transpose(-1, -2) @ poses @ turn[:, 1:]


def _turn(K: torch.Tensor, pixels: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """Where ``pixels`` (B, T, H, W, 2) (x, y) of a camera turned by ``angles`` (B, T) about its optical
    axis lie in the unturned camera's frame: ``K Rz(a) K^-1 p`` (the turn keeps depth)."""
    fx, fy, cx, cy = (K[:, i, j, None, None, None] for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    u, v = (pixels[..., 0] - cx) / fx, (pixels[..., 1] - cy) / fy
    cos, sin = angles.cos()[..., None, None], angles.sin()[..., None, None]
    return torch.stack((fx * (cos * u - sin * v) + cx, fy * (sin * u + cos * v) + cy), dim=-1)


def _sample(x: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """``x`` (B, T, C, H, W) read at ``pixels`` (B, T, H, W, 2) (bilinear, the border extended)."""
    B, T, C, H, W = x.shape
    scale = torch.tensor([2.0 / W, 2.0 / H], dtype=pixels.dtype, device=pixels.device)
    grid = ((pixels + 0.5) * scale - 1.0).reshape(B * T, H, W, 2)
    out = F.grid_sample(
        x.reshape(B * T, C, H, W).to(grid.dtype), grid, align_corners=False, padding_mode="border"
    )
    return out.reshape(x.shape)


def rolled_windows(
    inputs: Inputs, targets: torch.Tensor, angles: torch.Tensor
) -> tuple[Inputs, torch.Tensor]:
    """Windows seen by cameras each turned about its optical axis, frame j by ``angles[:, j]`` ((B, L)
    radians): frames resampled, flow matched anew, targets by :func:`roll_poses`."""
    frames, K = inputs["frames"], inputs["K"].float()
    (B, L), (H, W) = frames.shape[:2], frames.shape[-2:]
    angles = angles.to(torch.float32)
    xs, ys = (torch.arange(n, dtype=K.dtype, device=K.device) for n in (W, H))
    grid = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=-1)  # (H, W, 2) pixel coordinates
    source = _turn(K, grid.expand(B, L, H, W, 2), angles)
    turned = _sample(frames, source)
    out = dict(inputs)
    out["frames"] = turned if frames.is_floating_point() else turned.round().clamp(0, 255).to(frames.dtype)
    if "flow" in inputs:
        flow = inputs["flow"]
        old_match = source[:, :-1] + _sample(flow, source[:, :-1]).movedim(2, -1)  # (B, P, H, W, 2)
        match = _turn(K, old_match, -angles[:, 1:])
        out["flow"] = (match - grid).movedim(-1, 2).to(flow.dtype)
    return out, roll_poses(targets, angles.to(targets.dtype))


TRANSFORMS = (Mirror, Roll)

Transform = Mirror | Roll


def spec(transform: Any) -> dict[str, Any]:
    """A transform as a config a checkpoint can hold: ``{"_target_": class path, **fields}``."""
    return {"_target_": f"{type(transform).__module__}.{type(transform).__qualname__}", **vars(transform)}
