"""Batch transforms: the training augmentations, each a small class applied to a batch on its device.

A transform maps ``(inputs, targets, generator) -> (inputs, targets)``, where ``inputs`` holds ``frames``
(B, L, 3, H, W) uint8 (float in [0, 255] after :class:`Jitter`), ``K`` (B, 3, 3) pixels and optionally
``flow`` (B, L-1, 2, H, W) pixels, and ``targets`` is (B, L-1, 4, 4), the relative poses
``inv(T_w_k) @ T_w_{k+1}``. Random draws come from ``generator`` (a CPU generator; None: torch's global
one), one draw per window, so that a window's pairs stay consistent. ``data.transforms`` lists them in the
order they apply (:class:`lossvo.data.datamodules.VODataModule`).

The mirror of a world seen through a camera is the conjugation by the reflection of the camera's x axis,
S = diag(-1, 1, 1, 1): :func:`mirror_poses` (targets, and predictions at inference), :func:`mirror_inputs`
(frames, flow and K).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from lossvo import geometry
from lossvo.checks import is_number
from lossvo.console import UserError
from lossvo.data import flow as optical_flow
from lossvo.geometry import camera

Inputs = dict[str, torch.Tensor]

STANDSTILL_NOISE = 1.5
"""Standard deviation (grey levels) of the sensor noise added to each frame of a standing window."""


def mirror_poses(poses: torch.Tensor) -> torch.Tensor:
    """Relative poses as the mirrored world shows them: ``S @ T @ S`` with S = diag(-1, 1, 1, 1) (sideways
    translation, yaw and roll change sign); its own inverse.

    Args:
        poses: (..., 4, 4).
    Returns:
        (..., 4, 4).
    """
    sign = torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=poses.dtype).to(poses.device, non_blocking=True)
    return poses * (sign[:, None] * sign)


def mirror_inputs(inputs: Inputs) -> Inputs:
    """Inputs as the mirrored world looks through the mirrored camera: frames flipped left to right, the
    flow mirrored (:func:`lossvo.data.flow.mirror_flow`) and K's principal point mirrored
    (:func:`lossvo.geometry.camera.mirrored_intrinsics`, cx -> W - 1 - cx).

    Args:
        inputs: ``frames`` (..., 3, H, W), optionally ``flow`` (..., 2, H, W) and ``K`` (..., 3, 3).
    Returns:
        the same entries, mirrored (other entries as they are).
    """
    mirrored = {**inputs, "frames": inputs["frames"].flip(-1)}
    if "flow" in inputs:
        mirrored["flow"] = optical_flow.mirror_flow(inputs["flow"])
    if "K" in inputs:
        mirrored["K"] = camera.mirrored_intrinsics(inputs["K"], inputs["frames"].shape[-1])
    return mirrored


def _where(which: torch.Tensor, new: torch.Tensor, old: torch.Tensor) -> torch.Tensor:
    """``new`` in the selected windows, ``old`` elsewhere; which: (B,) bool on the tensors' device."""
    return torch.where(which.view(-1, *[1] * (old.dim() - 1)), new, old)


def _draw(p: float, size: int, generator: torch.Generator | None) -> torch.Tensor:
    """(size,) bool on the CPU, each True with probability ``p``."""
    return torch.rand(size, generator=generator) < p


def _check_probability(name: str, p: Any) -> None:
    if not (is_number(p) and 0.0 <= p <= 1.0):
        raise UserError(f"data.transforms: {name}.p: expected a probability in [0, 1], got {p!r}")


@dataclass(frozen=True)
class Standstill:
    """Replace a window, with probability ``p``, by the car standing still at its first frame: every frame
    the first plus fresh sensor noise (Gaussian, :data:`STANDSTILL_NOISE` grey levels, rounded to uint8),
    every target the identity, the flow zero. Any scene may then show no motion."""

    p: float

    def __post_init__(self) -> None:
        _check_probability("Standstill", self.p)

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        frames = inputs["frames"]
        which = _draw(self.p, frames.shape[0], generator)
        chosen = which.nonzero().flatten()  # drawn on the host: counted there, no wait for the device
        out = dict(inputs)
        if len(chosen):
            chosen = chosen.to(frames.device, non_blocking=True)
            frames, targets = frames.clone(), targets.clone()
            still = frames[chosen, :1].float().expand(-1, frames.shape[1], -1, -1, -1)
            same_device = generator is not None and generator.device == frames.device
            noise = torch.randn(
                still.shape, device=frames.device, generator=generator if same_device else None
            )
            frames[chosen] = (still + STANDSTILL_NOISE * noise).round().clamp(0, 255).to(frames.dtype)
            targets[chosen] = torch.eye(4, dtype=targets.dtype, device=targets.device)
            out["frames"] = frames
        if "flow" in inputs:
            moving = ~which.to(frames.device, non_blocking=True)
            out["flow"] = inputs["flow"] * moving.view(-1, 1, 1, 1, 1)
        return out, targets


@dataclass(frozen=True)
class Zoom:
    """See each window through a zoomed-in camera (TartanVO's intrinsics augmentation): a random window of
    1/sx by 1/sy of the frame (sx, sy drawn apart from U[1, ``factor``]) resized to the whole frame
    (bilinear); the flow resampled and scaled by (sx, sy), K turned into the window's K (fx sx, fy sy,
    principal point moved). Targets are unchanged."""

    factor: float

    def __post_init__(self) -> None:
        if not (is_number(self.factor) and 1.0 <= self.factor <= 4.0):
            raise UserError(f"data.transforms: Zoom.factor: expected a number in [1, 4], got {self.factor!r}")

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        return zoomed_windows(inputs, self.factor, generator), targets


def zoomed_windows(inputs: Inputs, zoom: float, generator: torch.Generator | None = None) -> Inputs:
    """Each window through a zoomed-in camera (:class:`Zoom`); four draws a window (sx, sy, x0, y0).

    Args:
        inputs: ``frames`` (B, L, C, H, W) uint8 or float, ``K`` (B, 3, 3) pixels, optionally ``flow``
            (B, P, 2, H, W) pixels; zoom: the largest factor (>= 1).
    Returns:
        the same entries, zoomed (other entries as they are).
    """
    frames, K = inputs["frames"], inputs["K"]
    B, H, W = frames.shape[0], frames.shape[-2], frames.shape[-1]
    draw = torch.rand(4, B, generator=generator).to(K.device, torch.float32, non_blocking=True)
    sx, sy = 1.0 + (zoom - 1.0) * draw[0], 1.0 + (zoom - 1.0) * draw[1]
    x0, y0 = draw[2] * W * (1.0 - 1.0 / sx), draw[3] * H * (1.0 - 1.0 / sy)  # window's corner, pixels
    theta = torch.zeros(B, 2, 3, device=K.device)
    theta[:, 0, 0], theta[:, 0, 2] = 1.0 / sx, 1.0 / sx + 2.0 * x0 / W - 1.0
    theta[:, 1, 1], theta[:, 1, 2] = 1.0 / sy, 1.0 / sy + 2.0 * y0 / H - 1.0

    def resample(x: torch.Tensor) -> torch.Tensor:  # (B, T, C, H, W) -> the same, each window its theta
        T, C = x.shape[1], x.shape[2]
        grid = F.affine_grid(theta.repeat_interleave(T, 0), [B * T, C, H, W], align_corners=False)
        out = F.grid_sample(
            x.reshape(B * T, C, H, W).float(), grid, align_corners=False, padding_mode="border"
        )
        return out.reshape(x.shape)

    out = dict(inputs)
    zoomed = resample(frames)
    out["frames"] = (
        zoomed.round().clamp(0, 255).to(frames.dtype) if not frames.is_floating_point() else zoomed
    )
    if "flow" in inputs:
        scale = torch.stack((sx, sy), 1).view(B, 1, 2, 1, 1)
        out["flow"] = (resample(inputs["flow"]) * scale).to(inputs["flow"].dtype)
    K_out = K.clone()
    K_out[:, 0, 0], K_out[:, 1, 1] = K[:, 0, 0] * sx, K[:, 1, 1] * sy
    K_out[:, 0, 2] = (K[:, 0, 2] - x0 + 0.5) * sx - 0.5
    K_out[:, 1, 2] = (K[:, 1, 2] - y0 + 0.5) * sy - 0.5
    out["K"] = K_out
    return out


@dataclass(frozen=True)
class Mirror:
    """Mirror a window left to right with probability ``p``: its inputs by :func:`mirror_inputs` (frames,
    flow, K's principal point), its targets by :func:`mirror_poses`. Exact for the mirrored world seen
    through the mirrored camera: left and right turns in equal numbers."""

    p: float

    def __post_init__(self) -> None:
        _check_probability("Mirror", self.p)

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        which = _draw(self.p, inputs["frames"].shape[0], generator).to(targets.device, non_blocking=True)
        mirrored = mirror_inputs(inputs)
        out = {
            k: _where(which, mirrored[k], v) if k in ("frames", "flow", "K") else v for k, v in inputs.items()
        }
        return out, _where(which, mirror_poses(targets), targets)


@dataclass(frozen=True)
class Roll:
    """Turn the cameras of a window about their optical axes, with probability ``p``: each frame after the
    first by its own angle drawn from U[-``max_rad``, ``max_rad``] (radians), so that every pair gains a
    roll the data may lack (:func:`rolled_windows`). A turn about the camera's centre moves every pixel by
    a map that depends on K alone, not on depth, so frames and flow follow exactly (the flow of later
    pairs is resampled, bilinear, the border extended)."""

    p: float
    max_rad: float

    def __post_init__(self) -> None:
        _check_probability("Roll", self.p)
        if not (is_number(self.max_rad) and 0.0 <= self.max_rad <= 0.5):
            raise UserError(
                f"data.transforms: Roll.max_rad: expected radians in [0, 0.5], got {self.max_rad!r}"
            )

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        B, L = inputs["frames"].shape[:2]
        which = _draw(self.p, B, generator)
        draw = (2.0 * torch.rand(B, L - 1, generator=generator) - 1.0) * self.max_rad * which[:, None]
        angles = torch.cat((torch.zeros(B, 1), draw), 1).to(targets.device, non_blocking=True)
        return rolled_windows(inputs, targets, angles)


def roll_poses(poses: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """Relative poses between cameras each turned about its optical axis: ``Rz(a_k)^T T_k Rz(a_k+1)``, where
    ``T_w_j`` becomes ``T_w_j Rz(a_j)``.

    Args:
        poses: (B, P, 4, 4) ``inv(T_w_k) @ T_w_{k+1}``; angles: (B, P + 1) radians, one a frame.
    Returns:
        (B, P, 4, 4).
    """
    cos, sin = angles.cos(), angles.sin()
    turn = torch.zeros(*angles.shape, 4, 4, dtype=poses.dtype, device=poses.device)
    turn[..., 0, 0], turn[..., 0, 1], turn[..., 1, 0], turn[..., 1, 1] = cos, -sin, sin, cos
    turn[..., 2, 2] = turn[..., 3, 3] = 1.0
    return turn[:, :-1].transpose(-1, -2) @ poses @ turn[:, 1:]


def _turn(K: torch.Tensor, pixels: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """Where pixels of a camera turned by ``angles`` about its optical axis lie in the unturned camera's
    frame: ``K Rz(a) K^-1 p`` (an affine map: the turn keeps depth).

    Args:
        K: (B, 3, 3) pixels; pixels: (B, T, H, W, 2) coordinates (x, y), pixel centres at integers;
            angles: (B, T) radians.
    Returns:
        (B, T, H, W, 2).
    """
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
    """Windows seen by cameras each turned about its optical axis (:class:`Roll`): frame j by
    ``angles[:, j]``. Frame j becomes ``I(K Rz(a_j) K^-1 p)``; pair k's flow, at pixel p of the turned
    frame k, the turned frame k+1's pixel of the old match minus p; targets by :func:`roll_poses`.

    Args:
        inputs: ``frames`` (B, L, C, H, W), ``K`` (B, 3, 3) pixels, optionally ``flow`` (B, L-1, 2, H, W)
            pixels; targets: (B, L-1, 4, 4); angles: (B, L) radians.
    Returns:
        the same entries, turned (other entries as they are), and the targets.
    """
    frames, K = inputs["frames"], inputs["K"].float()
    (B, L), (H, W) = frames.shape[:2], frames.shape[-2:]
    angles = angles.to(torch.float32)
    ys, xs = torch.meshgrid(
        torch.arange(H, dtype=K.dtype, device=K.device),
        torch.arange(W, dtype=K.dtype, device=K.device),
        indexing="ij",
    )
    grid = torch.stack((xs, ys), dim=-1)  # (H, W, 2) pixel coordinates
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


@dataclass(frozen=True)
class Reverse:
    """Play a window backwards with probability ``p``: frames in reverse order, targets the inverse
    relative poses in reverse order (frame k seen from frame k+1), which is exact. Not with flow (the cache
    holds each pair's forward flow only)."""

    p: float

    def __post_init__(self) -> None:
        _check_probability("Reverse", self.p)

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        frames = inputs["frames"]
        which = _draw(self.p, frames.shape[0], generator).to(frames.device, non_blocking=True)
        backwards = geometry.pose_inverse(targets).flip(1)
        return {**inputs, "frames": _where(which, frames.flip(1), frames)}, _where(which, backwards, targets)


@dataclass(frozen=True)
class Jitter:
    """Brightness and contrast jitter, one draw of each per window: ``(x - 127.5) (1 + 0.4 g) + 127.5 +
    50 b`` with g, b ~ U[-0.5, 0.5], clamped to [0, 255] and rounded; frames become float."""

    def __call__(
        self, inputs: Inputs, targets: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[Inputs, torch.Tensor]:
        return {**inputs, "frames": jitter(inputs["frames"].float(), generator).round()}, targets


def jitter(frames: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Brightness and contrast jitter (:class:`Jitter`) before rounding.

    Args:
        frames: (B, L, 3, H, W) float in [0, 255].
    Returns:
        (B, L, 3, H, W) float in [0, 255].
    """
    draw = torch.rand(2, frames.shape[0], 1, 1, 1, 1, generator=generator) - 0.5
    gain, bias = draw.to(frames.device, non_blocking=True)
    return ((frames - 127.5) * (1.0 + 0.4 * gain) + 127.5 + 50.0 * bias).clamp(0.0, 255.0)


TRANSFORMS = (Standstill, Zoom, Mirror, Roll, Reverse, Jitter)
"""The batch transforms, in the order the configs list them."""

Transform = Standstill | Zoom | Mirror | Roll | Reverse | Jitter


def spec(transform: Any) -> dict[str, Any]:
    """A transform as a config a checkpoint can hold: ``{"_target_": class path, **fields}``."""
    return {"_target_": f"{type(transform).__module__}.{type(transform).__qualname__}", **vars(transform)}


LEGACY_TRANSFORMS = ("standstill", "zoom", "mirror", "reverse", "augment")
"""Augmentation arguments of earlier versions, in the order they applied; :func:`upgrade_description`
turns them into ``transforms``."""


def upgrade_description(data: Any) -> Any:
    """A checkpoint's data description (:meth:`lossvo.data.datamodules.VODataModule.description`) as the
    current datamodule takes it: the augmentation arguments of checkpoints written before batch transforms
    (``standstill``, ``zoom``, ``mirror``, ``reverse`` probabilities or factors, ``augment`` true or
    false) turned into the ``transforms`` list that applies them in the same order; the rest as it is."""
    if not isinstance(data, Mapping) or not set(LEGACY_TRANSFORMS) & set(data):
        return data
    made = {
        "standstill": lambda v: Standstill(v) if v > 0 else None,
        "zoom": lambda v: Zoom(v) if v > 1 else None,
        "mirror": lambda v: Mirror(v) if v > 0 else None,
        "reverse": lambda v: Reverse(v) if v > 0 else None,
        "augment": lambda v: Jitter() if v else None,
    }
    listed = [made[key](data[key]) for key in LEGACY_TRANSFORMS if key in data]
    upgraded = {k: v for k, v in data.items() if k not in LEGACY_TRANSFORMS}
    return {**upgraded, "transforms": [spec(t) for t in listed if t is not None]}
