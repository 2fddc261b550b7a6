"""LightningDataModules for datasets in their own layouts (KITTI odometry, TUM RGB-D, EuRoC, TartanAir, MIMIR:
:mod:`lossvo.data.layouts`) and for the embedded synthetic KITTI-layout dataset.

A sample is a window of ``seq_len`` consecutive frames and its ``seq_len - 1`` relative-pose targets;
a batch is a dict, as the model receives it::

    "frames":  (B, seq_len, 3, H, W) float32, normalised per channel
    "targets": (B, seq_len - 1, 4, 4) float32, inv(T_w_k) @ T_w_{k+1} computed in float64
    "K":       (B, 3, 3) float32, the intrinsics of the cached frames (pixels)
    "flow":    (B, seq_len - 1, 2, H, W) float32, optical flow of each pair in pixels (with ``flow``)

The loaders carry frames as uint8 (a window is one copy out of the memory map) and the DataModule
normalises them on the training device in ``on_after_batch_transfer``, Lightning's hook for this.

Training windows start every ``stride`` frames; validation and test windows tile each sequence
(:mod:`lossvo.data.windows`), so that every consecutive pair of a sequence is seen exactly once. No window
spans a gap in a sequence's timestamps (frames its reader dropped): tiles cut there, the pair across a gap a
window of its own.
``prepare_data`` checks the dataset (one clear error naming the file) and builds the frame cache
(:mod:`lossvo.data.frame_cache`) before anything trains. Normalisation statistics come from the training
sequences only, or are FlowNet's ``x / 255 - 0.5`` when its weights are used.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from collections.abc import Iterator, Mapping
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
import torch.nn.functional as F
from filelock import FileLock
from torch.utils.data import BatchSampler, DataLoader, Dataset, Sampler, SequentialSampler

from lossvo import geometry
from lossvo.atomic import write_text_atomic
from lossvo.checks import is_integer, is_number
from lossvo.data import flow as optical_flow
from lossvo.data import frame_cache, layouts, resident, synthetic, windows
from lossvo.data.kitti import relative_targets
from lossvo.data.sequence import Sequence, split_names
from lossvo.data.synthetic import routes
from lossvo.geometry import camera

log = logging.getLogger("lossvo")

PAPER_TRAIN = ("00", "02", "03", "04", "05", "06", "08")
PAPER_VAL = ("07", "09")
PAPER_TEST = ("00", "01", "02", "03", "04", "05", "06", "07", "08", "09", "10")
NORMALIZATIONS = ("dataset", "flownet")


def _names(value: str | int | Seq[str | int], key: str) -> tuple[str, ...]:
    """Sequence names from a config value: ["00", "07"], "00,07", [0, 7] or 7 (Hydra turns 07 into 7)."""
    names = split_names(value)
    if "" in names:
        raise ValueError(f"data.{key}: empty sequence name in {value!r}")
    return tuple(names)


def _statistics(value: Mapping[str, Seq[float]] | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(mean (3,), std (3,)) from ``{"mean": [3], "std": [3]}``; one line naming the problem otherwise."""
    if value is None:
        return None
    try:
        mean, std = (np.asarray(value[key], dtype=np.float64) for key in ("mean", "std"))
    except (KeyError, TypeError, ValueError):
        mean = std = np.zeros(0)
    if mean.shape != (3,) or std.shape != (3,) or not np.all(std > 0) or not np.isfinite(mean).all():
        raise ValueError(
            f"data.statistics: expected {{mean: [3 floats], std: [3 floats > 0]}}, got {value!r}"
        )
    return mean, std


def _primitive(value: Any) -> Any:
    """A config value as plain Python (lists, dicts, scalars): what a checkpoint may hold."""
    if isinstance(value, Mapping):
        return {str(k): _primitive(v) for k, v in value.items()}
    if isinstance(value, Seq) and not isinstance(value, str):
        return [_primitive(v) for v in value]
    return value


class WindowDataset(Dataset):
    """Windows of cached frames with their relative-pose targets.

    Items are dicts: ``frames`` (L, 3, H, W) uint8, ``targets`` (L - 1, 4, 4) float32, ``K`` (3, 3)
    float32 and, with flow, ``flow`` (L - 1, 2, H, W) float16: a window costs one memory copy. Training
    windows (:func:`lossvo.data.windows.training_starts`) have ``seq_len`` frames, start every ``stride``
    frames and exist at each frame step s of ``steps``: every s-th frame, with targets ``inv(T_w_k) @
    T_w_{k+s}`` computed from the poses in float64 (s = 2 doubles the speeds and rotations the network
    sees). Tiled windows (``tiled=True``, validation and test) follow :func:`lossvo.data.windows.tile`:
    every consecutive pair exactly once, the last window of a sequence possibly shorter. Conversion to
    float, normalisation and augmentation happen per batch on the training
    device (:meth:`KittiDataModule.on_after_batch_transfer`), which also moves 4x fewer bytes to the GPU.
    The memory maps are opened lazily in each process (a pickled memmap would be copied whole into every
    DataLoader worker).

    Args:
        cache_files: one cached frame array per sequence; poses: (N_i, 4, 4) T_w_c per sequence.
        seq_len: frames per window; stride: frames between training window starts; steps: frame steps of
            the training windows (1: consecutive); tiled: tile the sequences instead (stride, steps unused).
        intrinsics: (3, 3) K of each sequence's cached frames (None: the identity).
        flow_files: step -> one cached flow array per sequence (:mod:`lossvo.data.flow`), for every step
            used; None: no flow.
        times: (N_i,) timestamps (s) per sequence: training windows never span a gap in them
            (:func:`lossvo.data.windows.gaps`); None: no gaps.
    """

    def __init__(
        self, cache_files: list[Path], poses: list[np.ndarray], seq_len: int, stride: int = 1,
        steps: Seq[int] = (1,), tiled: bool = False, intrinsics: list[np.ndarray] | None = None,
        flow_files: dict[int, list[Path]] | None = None, times: list[np.ndarray] | None = None,
    ) -> None:  # fmt: skip
        self.cache_files = cache_files
        self.flow_files = flow_files
        self.seq_len = seq_len
        Ks = intrinsics if intrinsics is not None else [np.eye(3)] * len(poses)
        self.intrinsics = [torch.from_numpy(np.asarray(K, dtype=np.float32)) for K in Ks]
        steps = (1,) if tiled else tuple(steps)
        self.targets = {
            s: [torch.from_numpy(relative_targets(p, s).astype(np.float32)) for p in poses] for s in steps
        }
        lengths = [len(p) for p in poses]
        gap = [windows.gaps(t) for t in times] if times is not None else [None] * len(poses)
        rows = [
            self._tiles(i, n, seq_len, gap[i]) if tiled else self._training(i, n, seq_len, stride, s, gap[i])
            for s in steps for i, n in enumerate(lengths) if n >= 2
        ]  # fmt: skip
        self.index = np.concatenate(rows) if rows else np.zeros((0, 4), dtype=np.int64)
        self._frames: list[np.ndarray] | None = None
        self._flow: dict[int, list[np.ndarray]] | None = None

    @staticmethod
    def _training(
        seq: int, n: int, seq_len: int, stride: int, step: int, gap: np.ndarray | None
    ) -> np.ndarray:
        """(M, 4) rows (sequence, start, stop, step) of a sequence's training windows at one step."""
        starts = windows.training_starts(n, seq_len, stride, step, gap)
        stops = starts + step * (seq_len - 1) + 1
        return np.stack((np.full_like(starts, seq), starts, stops, np.full_like(starts, step)), axis=1)

    @staticmethod
    def _tiles(seq: int, n: int, seq_len: int, gap: np.ndarray | None) -> np.ndarray:
        """(M, 4) rows (sequence, start, stop, 1) of the windows tiling a sequence."""
        ranges = windows.tile(n, seq_len, gap)
        ones = np.ones(len(ranges), dtype=np.int64)
        return np.stack((seq * ones, ranges[:, 0], ranges[:, 1], ones), axis=1)

    @property
    def lengths(self) -> np.ndarray:
        """(M,) frames of each window."""
        return (self.index[:, 2] - self.index[:, 1] - 1) // self.index[:, 3] + 1

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_frames": None, "_flow": None}

    @property
    def frames(self) -> list[np.ndarray]:
        if self._frames is None:
            self._frames = [np.load(f, mmap_mode="r") for f in self.cache_files]
        return self._frames

    def __len__(self) -> int:
        return len(self.index)

    @property
    def flow(self) -> dict[int, list[np.ndarray]]:
        if self._flow is None:
            files = self.flow_files or {}
            self._flow = {step: [np.load(f, mmap_mode="r") for f in paths] for step, paths in files.items()}
        return self._flow

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        seq, start, stop, step = (int(v) for v in self.index[i])
        item = {
            "frames": torch.from_numpy(np.array(self.frames[seq][start:stop:step])),  # one copy
            "targets": self.targets[step][seq][start : stop - 1 : step],
            "K": self.intrinsics[seq],
        }
        if self.flow_files is not None:  # pair (k, k + step) is field k of the step's flow
            item["flow"] = torch.from_numpy(np.array(self.flow[step][seq][start : stop - 1 : step]))
        return item


def reverse_windows(
    frames: torch.Tensor, targets: torch.Tensor, which: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Play the selected windows backwards: frames in reverse order, and as targets the inverse
    relative poses in reverse order (frame k seen from frame k+1), which is exact.

    Args:
        frames: (B, L, 3, H, W); targets: (B, L-1, 4, 4); which: (B,) bool, the windows to reverse.
    Returns:
        frames, targets of the same shapes.
    """
    which = which.to(frames.device, non_blocking=True)
    backwards_targets = geometry.pose_inverse(targets).flip(1)
    return (
        torch.where(which.view(-1, 1, 1, 1, 1), frames.flip(1), frames),
        torch.where(which.view(-1, 1, 1, 1), backwards_targets, targets),
    )


def mirror_windows(
    frames: torch.Tensor, targets: torch.Tensor, which: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror the selected windows left to right: every frame flipped horizontally and every target
    conjugated by the reflection S = diag(-1, 1, 1, 1) of the camera's x axis, S @ T @ S (sideways
    translation, yaw and roll change sign). The mirrored frames are what the mirrored world looks like
    through a camera whose principal point is mirrored too (cx -> W - 1 - cx): exact for a centred
    principal point, and a shift of W - 1 - 2 cx pixels otherwise (about 4 px of 208 on the synthetic
    data, 26 px of 1241 on KITTI).

    Args:
        frames: (B, L, 3, H, W); targets: (B, L-1, 4, 4); which: (B,) bool, the windows to mirror.
    Returns:
        frames, targets of the same shapes.
    """
    which = which.to(frames.device, non_blocking=True)
    sign = torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=targets.dtype).to(targets.device, non_blocking=True)
    return (
        torch.where(which.view(-1, 1, 1, 1, 1), frames.flip(-1), frames),
        torch.where(which.view(-1, 1, 1, 1), targets * (sign[:, None] * sign), targets),
    )


def mirror_inputs(inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A sequence's inputs as a mirrored world looks through the mirrored camera: frames flipped left to
    right, the flow mirrored (:func:`lossvo.data.flow.mirror_flow`) and K's principal point mirrored
    (:func:`lossvo.data.camera.mirrored_intrinsics`), as :func:`mirror_windows` does in training.

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


def zoomed_windows(
    inputs: dict[str, torch.Tensor], zoom: float, generator: torch.Generator | None = None
) -> dict[str, torch.Tensor]:
    """Each window seen through a zoomed-in camera, as TartanVO's intrinsics augmentation does: a random
    window of 1/sx by 1/sy of the frame (sx, sy drawn apart from U[1, zoom], one draw a window) resized to the
    whole frame; the frames and flow resampled (bilinear), the flow scaled by (sx, sy) and K turned into the
    window's K (fx sx, fy sy, principal point moved): a training set of one camera then shows the network
    many, so that the intrinsics layer carries information.

    Args:
        inputs: ``frames`` (B, L, C, H, W) uint8 or float, ``K`` (B, 3, 3), optionally ``flow``
            (B, P, 2, H, W) in pixels; zoom: the largest factor (>= 1).
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


STANDSTILL_NOISE = 1.5
"""Standard deviation (grey levels) of the sensor noise added to each frame of a standing window."""


def standing_windows(
    frames: torch.Tensor, targets: torch.Tensor, which: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Turn the selected windows into a car standing still where the window starts: every frame the
    window's first with fresh sensor noise (Gaussian, STANDSTILL_NOISE grey levels), every target the
    identity. Any scene may then show no motion, so a network cannot read speed off the scene.

    Args:
        frames: (B, L, 3, H, W) uint8; targets: (B, L-1, 4, 4); which: (B,) bool, the windows to stop.
    Returns:
        frames, targets of the same shapes and dtypes.
    """
    chosen = which.cpu().nonzero().flatten()  # drawn on the host: counted there, no wait for the device
    if not len(chosen):
        return frames, targets
    chosen = chosen.to(frames.device, non_blocking=True)
    frames, targets = frames.clone(), targets.clone()
    still = frames[chosen, :1].float().expand(-1, frames.shape[1], -1, -1, -1)
    noisy = still + STANDSTILL_NOISE * torch.randn(still.shape, device=frames.device)
    frames[chosen] = noisy.round().clamp(0, 255).to(frames.dtype)
    targets[chosen] = torch.eye(4, dtype=targets.dtype, device=targets.device)
    return frames, targets


def jitter(frames: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Brightness and contrast jitter, one draw per window (keeps the window's pairs consistent).

    Args:
        frames: (B, L, 3, H, W) float in [0, 255].
    Returns:
        (B, L, 3, H, W) float in [0, 255].
    """
    draw = torch.rand(2, frames.shape[0], 1, 1, 1, 1, generator=generator) - 0.5
    gain, bias = draw.to(frames.device, non_blocking=True)
    return ((frames - 127.5) * (1.0 + 0.4 * gain) + 127.5 + 50.0 * bias).clamp(0.0, 255.0)


def _own_stream() -> torch.Generator:
    """A generator for a DataLoader's worker seeds, seeded with the run's seed: without one, every
    epoch's loader iterator draws from the global stream, which the network's dropout uses."""
    return torch.Generator().manual_seed(torch.initial_seed())


class EpochShuffle(Sampler[int]):
    """``count`` of ``n`` indices without replacement in a random order that depends on ``seed`` and the
    epoch only (Lightning calls :meth:`set_epoch` before every training epoch).

    Args:
        n: dataset size; count: indices per epoch (<= n); seed: the run's seed.
    """

    def __init__(self, n: int, count: int, seed: int) -> None:
        self.n, self.count, self.seed, self.epoch = n, count, seed, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __iter__(self) -> Iterator[int]:
        state = np.random.SeedSequence([self.seed % 2**63, self.epoch]).generate_state(2, dtype=np.uint32)
        generator = torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))
        return iter(torch.randperm(self.n, generator=generator)[: self.count].tolist())

    def __len__(self) -> int:
        return self.count


def _probability(value: Any) -> bool:
    return is_number(value) and 0.0 <= value <= 1.0


ARGUMENT_CHECKS: tuple[tuple[str, Any, str], ...] = (
    ("height", lambda v: is_integer(v, 16), "an integer >= 16 pixels"),
    ("width", lambda v: is_integer(v, 16), "an integer >= 16 pixels"),
    ("seq_len", lambda v: is_integer(v, 2), "an integer >= 2 frames"),
    ("stride", lambda v: is_integer(v, 1), "an integer >= 1"),
    ("keep_every", lambda v: is_integer(v, 1), "an integer >= 1 (frames)"),
    ("normalization", lambda v: v in NORMALIZATIONS, f"one of {NORMALIZATIONS}"),
    ("windows_per_epoch", lambda v: v is None or is_integer(v, 1), "null or an integer >= 1"),
    ("reverse", _probability, "a probability in [0, 1]"),
    ("standstill", _probability, "a probability in [0, 1]"),
    ("mirror", _probability, "a probability in [0, 1]"),
    ("zoom", lambda v: is_number(v) and 1.0 <= v <= 4.0, "a number in [1, 4] (1: no zoom)"),
    ("crop", lambda v: isinstance(v, bool), "true or false"),
    ("on_device", lambda v: v == "auto" or isinstance(v, bool), "auto, true or false"),
    ("device_budget_gb", lambda v: is_number(v) and v >= 0, "a number of GiB >= 0"),
)
"""(argument, test, what is expected) of the datamodule's scalar arguments."""


def _check_arguments(values: Mapping[str, Any]) -> None:
    """ValueError ``data.<argument>: expected <what>, got <value>`` at the first argument of
    :data:`ARGUMENT_CHECKS` that fails its test."""
    for key, fits, expected in ARGUMENT_CHECKS:
        if not fits(values[key]):
            raise ValueError(f"data.{key}: expected {expected}, got {values[key]!r}")


def _frame_steps(value: Any) -> tuple[int, ...]:
    """``data.frame_steps`` as distinct steps in order; ValueError naming the key otherwise."""
    steps = list(value) if isinstance(value, Seq) and not isinstance(value, str) else []
    if not steps or any(not is_integer(v, 1) for v in steps):
        raise ValueError(f"data.frame_steps: expected a list of integers >= 1 like [1, 2], got {value!r}")
    return tuple(dict.fromkeys(steps))


@dataclass(frozen=True)
class Source:
    """One dataset a datamodule reads: its ``layout`` (:data:`lossvo.data.layouts.LAYOUTS`), its ``root``,
    every how-many-th frame of its sequences is kept (``keep_every``) and the camera that replaces the one its
    reader gives (``camera``: K (3, 3) pixels and OpenCV distortion; None: the reader's)."""

    layout: str
    root: Path
    keep_every: int = 1
    camera: tuple[np.ndarray, np.ndarray] | None = None


def _camera(value: Any, key: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``{K: 3x3, distortion: [4, 5, 8, 12 or 14 numbers]}`` (distortion optional: zeros) as arrays, or None;
    ValueError naming ``key`` otherwise."""
    if value is None:
        return None
    if not isinstance(value, Mapping) or set(value) - {"K", "distortion"} or "K" not in value:
        raise ValueError(f"{key}: expected {{K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], distortion: [...]}}, "
                         f"got {value!r}")  # fmt: skip
    try:
        K = np.asarray(value["K"], dtype=np.float64)
        distortion = np.asarray(value.get("distortion") or np.zeros(5), dtype=np.float64)
    except (TypeError, ValueError):
        K, distortion = np.zeros(0), np.zeros(0)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{key}.K: expected a 3x3 matrix of pixels with fx, fy > 0, got {value['K']!r}")
    if distortion.shape not in ((4,), (5,), (8,), (12,), (14,)) or not np.isfinite(distortion).all():
        raise ValueError(
            f"{key}.distortion: expected 4, 5, 8, 12 or 14 numbers, got {value.get('distortion')!r}"
        )
    return K, distortion


class VODataModule(L.LightningDataModule):
    """A dataset in its own layout: cached frames, windows, the KITTI paper split by default.

    Args:
        root: the dataset's folder: for KITTI the one holding ``sequences/`` and ``poses/`` (or the folder
            holding ``dataset/``), for the other layouts the one holding the sequences.
        layout: the dataset's layout (:data:`lossvo.data.layouts.LAYOUTS`): ``kitti``, ``tum``, ``euroc``,
            ``tartanair`` or ``mimir``.
        train, val, test: sequence names as the dataset names them (``["00", "02"]`` or ``"00,02"``,
            ``["V1_02_medium"]``, ``["abandonedfactory/Easy/P000"]``).
        unseen: sequences of motion unlike the training split's (the synthetic dataset's unseen-motion
            routes), evaluated beside the test sequences and marked as such in reports; need poses.
        height, width: frame size in pixels after resizing (area interpolation).
        seq_len: frames per window (``seq_len - 1`` frame pairs).
        stride: frames between the starts of consecutive training windows.
        windows_per_epoch: if set, each epoch trains on this many windows drawn at random (without
            replacement) from all training windows: short epochs that still see every part of the data.
        batch_size, num_workers: DataLoader settings.
        cache_dir: where frames are cached; default ``$LOSSVO_CACHE`` or ``~/.cache/lossvo``.
        normalization: ``"dataset"`` (per-channel mean/std of the training sequences) or ``"flownet"``.
        augment: photometric jitter on training windows.
        reverse: probability of playing a training window backwards (frames in reverse order, targets
            the inverse relative poses in reverse order): exact geometry, twice the motions.
        standstill: probability of replacing a training window by the car standing still at its first
            frame (:func:`standing_windows`): no motion in any scene.
        frame_steps: frame steps of the training windows, e.g. ``[1, 2]``: every window start at each
            step (every s-th frame, targets recomputed from the poses), so larger steps add faster motion.
            Validation and evaluation always use consecutive frames.
        mirror: probability of mirroring a training window left to right (:func:`mirror_windows`):
            left and right turns in equal numbers, and scenes the network has not seen.
        statistics: ``{"mean": [3], "std": [3]}`` per channel of ``x / 255``: the normalisation of a
            trained network (its checkpoint's), used instead of computing it from the training split,
            which may then be empty (evaluation on data that holds only test sequences).
        flow: optical flow cached beside the frames (:mod:`lossvo.data.flow`): ``"dis"``,
            ``"farneback"`` or ``"none"``; for every frame pair training (each of ``frame_steps``) and
            evaluation (consecutive frames) use. flow_preset: DIS's preset (ultrafast, fast, medium).
            flow_scale: the flow is computed on the source images resized to ``flow_scale`` times
            (height, width), then resized to (height, width) (:class:`lossvo.data.flow.FlowSetting`).
        crop: cut each frame's centred window of the (height, width) aspect ratio before resizing it (K
            follows), so that pixels keep their shape; false: the whole frame, resized (anisotropically when
            the aspect ratios differ).
        zoom: the largest factor of the zoom augmentation of training windows (:func:`zoomed_windows`:
            random windows of the frame resized to it, K following); 1: none.
        camera: ``{K: 3x3, distortion: [k1, k2, p1, p2, k3]}`` replacing the camera the reader gives every
            sequence (pixels of the frames on disk; e.g. a TUM sequence recorded with another camera); null:
            the reader's.
        keep_every: keep every n-th frame of each sequence (the others are never read): matches frame rates
            across datasets (3 turns TUM's 30 Hz into KITTI's 10 Hz). Unlike ``frame_steps`` it applies to
            every split, evaluation included.
        on_device: where training and validation batches are assembled (:mod:`lossvo.data.resident`):
            ``auto``, on an accelerator (a GPU) when the splits' cached arrays fit ``device_budget_gb``
            there, else by the host loader; ``true``, on the training device whenever they fit, a CPU
            included; ``false``, always by the host loader. Both give the same batches; the run's log says
            which one assembles them. Several processes (DDP) always use the host loader.
        device_budget_gb: the most GiB of frames and flow kept on the device.

    Frames with distortion are undistorted once, when the frame cache is built
    (:func:`lossvo.data.frame_cache.undistortion`); :meth:`intrinsics` is K of the cached frames.
    :meth:`description` records the arguments, the dataset root and the normalisation statistics: a
    checkpoint stores it (:mod:`lossvo.training.checkpoints`), so that evaluation needs nothing else.
    """

    def __init__(
        self,
        root: str,
        train: Seq[str] | str = PAPER_TRAIN,
        val: Seq[str] | str = PAPER_VAL,
        test: Seq[str] | str = PAPER_TEST,
        unseen: Seq[str] | str = (),
        height: int = 184,
        width: int = 608,
        seq_len: int = 7,
        stride: int = 1,
        batch_size: int = 8,
        num_workers: int = 2,
        cache_dir: str | None = None,
        normalization: str = "dataset",
        augment: bool = False,
        reverse: float = 0.0,
        standstill: float = 0.0,
        pin_memory: bool = False,
        windows_per_epoch: int | None = None,
        frame_steps: Seq[int] = (1,),
        mirror: float = 0.0,
        statistics: Mapping[str, Seq[float]] | None = None,
        flow: str = "none",
        flow_preset: str = "medium",
        flow_scale: float = 1.0,
        layout: str = "kitti",
        keep_every: int = 1,
        crop: bool = False,
        zoom: float = 1.0,
        camera: Mapping[str, Any] | None = None,
        on_device: bool | str = "auto",
        device_budget_gb: float = 8.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(logger=False)
        _check_arguments({
            "height": height, "width": width, "seq_len": seq_len, "stride": stride, "keep_every": keep_every,
            "normalization": normalization, "windows_per_epoch": windows_per_epoch, "reverse": reverse,
            "standstill": standstill, "mirror": mirror, "zoom": zoom, "crop": crop, "on_device": on_device,
            "device_budget_gb": device_budget_gb,
        })  # fmt: skip
        self.root = Path(root).expanduser()
        self.layout = layouts.check_layout(layout)
        self.sources = {"": Source(self.layout, self.root, int(keep_every), _camera(camera, "data.camera"))}
        """The datasets read, by key: one, keyed ``""``, whose sequences are named as it names them; several
        (:class:`MultiDataModule`), whose sequences are named ``<key>/<name>``."""
        self.splits = {
            "train": _names(train, "train"),
            "val": _names(val, "val"),
            "test": _names(test, "test"),
            "unseen": _names(unseen, "unseen"),
        }
        self.statistics = _statistics(statistics)
        self.flow = optical_flow.FlowSetting(flow, flow_preset, flow_scale)
        if not self.splits["train"] and self.statistics is None:
            raise ValueError("data.train: expected at least one training sequence")
        self.frame_steps = _frame_steps(frame_steps)
        if self.flow.enabled and reverse > 0:
            raise ValueError(
                f"data.reverse: expected 0 with data.flow={flow} (the cache holds each pair's forward "
                f"flow only), got {reverse!r}"
            )
        self.height, self.width, self.seq_len, self.stride = height, width, seq_len, stride
        self.batch_size, self.num_workers, self.pin_memory = batch_size, num_workers, pin_memory
        self.windows_per_epoch = windows_per_epoch
        self.cache_dir = Path(cache_dir).expanduser() if cache_dir else frame_cache.default_cache_dir()
        self.normalization, self.augment, self.reverse = normalization, augment, float(reverse)
        self.standstill, self.mirror = float(standstill), float(mirror)
        self.crop, self.zoom = crop, float(zoom)
        self.on_device, self.device_budget_gb = on_device, float(device_budget_gb)
        self.resident: dict[str, resident.ResidentWindows] | None = None  # by split, once decided
        self.sequences: dict[str, Sequence] = {}
        self.mean: np.ndarray | None = None  # per-channel statistics, set by setup
        self.std: np.ndarray | None = None
        self.datasets: dict[str, WindowDataset] = {}
        self._cameras: dict[str, np.ndarray] = {}  # K of each sequence's cached frames (intrinsics)

    # -- preparation: check everything, build the cache, compute statistics --------------------------

    @property
    def all_names(self) -> list[str]:
        return sorted(set().union(*self.splits.values()))

    @property
    def evaluated(self) -> list[str]:
        """The sequences a trained network is evaluated on: test, then unseen-motion ones."""
        return list(dict.fromkeys(self.splits["test"] + self.splits["unseen"]))

    def source_of(self, name: str) -> tuple[Source, str]:
        """The dataset a sequence is read from and the sequence's name there."""
        if "" in self.sources:
            return self.sources[""], name
        key, _, local = name.partition("/")
        return self.sources[key], local

    def _load_metadata(self) -> None:
        """Read every sequence's metadata (every ``keep_every``-th frame); only test sequences may lack
        poses (KITTI 11-21). ``sequences`` is keyed by the names of :attr:`splits`; each Sequence keeps the
        name its dataset gives it."""
        labelled = set(self.splits["train"]) | set(self.splits["val"]) | set(self.splits["unseen"])
        self.sequences, self._cameras = {}, {}
        for name in self.all_names:
            source, local = self.source_of(name)
            root = layouts.dataset_root(source.layout, source.root)
            seq = layouts.load_sequence(source.layout, root, local, require_poses=name in labelled)
            if source.camera is not None:
                seq = dataclasses.replace(seq, K=source.camera[0], distortion=source.camera[1])
            self.sequences[name] = seq.every(source.keep_every)

    def load_metadata(self) -> None:
        """Read and check every sequence's poses, calibration and image list, without building the
        frame cache (for tools that need the ground truth or the PNGs only)."""
        self._load_metadata()

    def cache_path(self, name: str | None = None) -> Path:
        """The frame-cache folder of sequence ``name``'s dataset (None: of the only dataset)."""
        source = next(iter(self.sources.values())) if name is None else self.source_of(name)[0]
        root = layouts.dataset_root(source.layout, source.root).resolve()
        folder = frame_cache.cache_folder(self.cache_dir, root, self.height, self.width)
        suffix = (f"-every{source.keep_every}" if source.keep_every > 1 else "") + (
            "-crop" if self.crop else ""
        )
        return folder.with_name(folder.name + suffix) if suffix else folder

    def _frame_files(self, name: str) -> tuple[Path, Path]:
        """The cached frames (.npy) and their manifest (.json) of sequence ``name``."""
        return frame_cache.files(self.cache_path(name), self.sequences[name].name)

    def _flow_file(self, name: str, step: int) -> Path:
        return optical_flow.flow_file(self.cache_path(name), self.sequences[name].name, step, self.flow)

    def _frames_source(self, name: str) -> dict:
        """What sequence ``name``'s cached frames were built from (``frame_cache.source_of``)."""
        return frame_cache.source_of(self.cache_path(name), self.sequences[name].name)

    def _ensure_frames(self) -> dict[str, np.ndarray]:
        """Every sequence's cached frames, built where missing or stale."""
        return {
            n: frame_cache.ensure_frames(self.cache_path(n), s, self.height, self.width, crop=self.crop)
            for n, s in self.sequences.items()
        }

    def prepare_data(self) -> None:
        """Check the dataset and build the frame cache and the normalisation statistics (once)."""
        self._load_metadata()
        frames = self._ensure_frames()
        self._stats(frames)
        self._ensure_flow(frames)

    def _stats_path(self) -> Path:
        """Beside the first training sequence's frames, named after the training split."""
        key = hashlib.sha1(",".join(self.splits["train"]).encode()).hexdigest()[:10]
        return self.cache_path(self.splits["train"][0]) / f"stats-{key}.json"

    def _stats(self, frames: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Per-channel mean/std: given (``statistics``), FlowNet's, or of the training sequences (cached
        with the frames; pooled over every training sequence of every dataset)."""
        if self.statistics is not None:
            return self.statistics
        if self.normalization == "flownet":
            return np.full(3, 0.5), np.ones(3)  # (x/255 - 0.5) / 1
        path = self._stats_path()
        sources = {n: self._frames_source(n) for n in self.splits["train"]}
        try:
            saved = json.loads(path.read_text())
            if saved["sources"] == sources:
                return np.array(saved["mean"]), np.array(saved["std"])
        except (OSError, ValueError, KeyError):
            pass
        mean, std = frame_cache.channel_stats([frames[n] for n in self.splits["train"]])
        write_text_atomic(path, json.dumps({"train": self.splits["train"], "sources": sources,
                                            "mean": mean.tolist(), "std": std.tolist()}))  # fmt: skip
        return mean, std

    def flow_steps(self) -> dict[str, tuple[int, ...]]:
        """Sequence -> the frame steps of the pairs a network sees in it: each of ``frame_steps`` in a
        training sequence, and 1 (consecutive frames) in every sequence."""
        train = set(self.splits["train"])
        return {n: tuple(sorted({1, *(self.frame_steps if n in train else ())})) for n in self.all_names}

    def _ensure_flow(self, frames: dict[str, np.ndarray]) -> dict[tuple[str, int], np.ndarray]:
        """The cached flow of every (sequence, step) of :meth:`flow_steps`, computed where missing or
        stale; none without ``flow``."""
        if not self.flow.enabled:
            return {}
        seqs = self.sequences
        return {
            (n, step): optical_flow.ensure_flow(
                self.cache_path(n), seqs[n].name, frames[n], self._frames_source(n), step, self.flow,
                seqs[n].images, undistort=frame_cache.undistortion(seqs[n]), crop=self.crop,
            )
            for n, steps in self.flow_steps().items() for step in steps
        }  # fmt: skip

    def setup(self, stage: str | None = None) -> None:
        """Open the cache (rebuilding anything missing or stale) and build the split datasets."""
        if self.datasets:
            return
        self._load_metadata()
        frames = self._ensure_frames()
        self.mean, self.std = self._stats(frames)
        self._ensure_flow(frames)
        for split, names in self.splits.items():
            labelled = [(n, p) for n in names if (p := self.sequences[n].poses) is not None]  # labelled ones
            steps = (1,) if split != "train" else self.frame_steps
            flow_files = None if not self.flow.enabled else {
                step: [self._flow_file(n, step) for n, _ in labelled] for step in steps
            }  # fmt: skip
            self.datasets[split] = WindowDataset(
                [self._frame_files(n)[0] for n, _ in labelled], [p for _, p in labelled],
                self.seq_len, self.stride, self.frame_steps, tiled=split != "train",
                intrinsics=[self.intrinsics(n) for n, _ in labelled], flow_files=flow_files,
                times=[self.sequences[n].times for n, _ in labelled],
            )  # fmt: skip
        if len(self.datasets["train"]) == 0 and self.splits["train"]:
            shortest = min(len(self.sequences[n].images) for n in self.splits["train"])
            raise ValueError(f"data.seq_len: {self.seq_len} frames is longer than every training sequence "
                             f"(shortest: {shortest} frames)")  # fmt: skip

    def description(self) -> dict[str, Any]:
        """What a network trained on this data depends on, as primitives (a checkpoint's ``data``):
        ``_target_`` (this class) and the constructor's arguments, ``root`` absolute, and, after
        :meth:`setup` (None before), ``statistics`` ``{"mean": [3], "std": [3]}`` and ``intrinsics``, the
        (3, 3) K of each training sequence's cached frames (pixels)."""
        config = {key: _primitive(value) for key, value in self.hparams.items()}
        if config.get("root") is not None:
            config["root"] = str(Path(config["root"]).expanduser().resolve())
        stats = None if self.mean is None or self.std is None else {
            "mean": [float(v) for v in self.mean], "std": [float(v) for v in self.std]
        }  # fmt: skip
        target = f"{type(self).__module__}.{type(self).__qualname__}"
        cameras = {n: self.intrinsics(n).tolist() for n in self.splits["train"]} if self.datasets else None
        return {"_target_": target, **config, "statistics": stats, "dataset_root": str(self.dataset_root()),
                "intrinsics": cameras}  # fmt: skip

    def dataset_root(self) -> Path:
        """The absolute folder the layout's reader reads (for KITTI the one holding ``sequences/``); with
        several datasets, the folder their roots share."""
        roots = [str(layouts.dataset_root(s.layout, s.root).resolve()) for s in self.sources.values()]
        return Path(os.path.commonpath(roots))

    def intrinsics(self, name: str) -> np.ndarray:
        """(3, 3) float64 K of a sequence's cached frames: its camera's K (of the undistorted frames where
        they are undistorted: :func:`lossvo.data.frame_cache.source_intrinsics`), resized from the source
        images' size to (height, width) (:func:`lossvo.data.camera.resized_intrinsics`); after
        :meth:`setup`; read once a sequence."""
        if name in self._cameras:
            return self._cameras[name].copy()
        manifest = json.loads(self._frame_files(name)[1].read_text())
        source = tuple(manifest["source_size_hw"])
        K = frame_cache.source_intrinsics(self.sequences[name])
        if self.crop:
            box = frame_cache.centre_crop(source, (self.height, self.width))
            K, source = frame_cache.cropped_intrinsics(K, box), box[2:]
        self._cameras[name] = camera.resized_intrinsics(K, source, (self.height, self.width))
        return self._cameras[name].copy()

    # -- where batches are assembled -----------------------------------------------------------------

    def resident_windows(self, split: str) -> resident.ResidentWindows | None:
        """The split's windows kept on the training device, or None where the host loader assembles its
        batches (:attr:`on_device`). Decided once, for the training and validation splits together, and
        said in the log."""
        if self.resident is None:
            self.resident = self._make_resident(self._training_device())
        if self.resident and split not in self.resident:  # the test split, asked for later
            self.resident[split] = self._resident_split(split, next(iter(self.resident.values())).device)
        return self.resident.get(split)

    def _training_device(self) -> torch.device:
        """The device the attached trainer trains on; the CPU without one."""
        strategy = getattr(self.trainer, "strategy", None)
        return getattr(strategy, "root_device", torch.device("cpu"))

    def _make_resident(self, device: torch.device) -> dict[str, resident.ResidentWindows]:
        """The training and validation splits' windows on ``device`` where :attr:`on_device` and the budget
        allow, else nothing (the host loader); one log line either way."""
        splits = [s for s in ("train", "val") if s in self.datasets]
        size = sum(resident.resident_bytes(*self._arrays(s)) for s in splits) / resident.GIB
        setting = f"data.on_device={str(self.on_device).lower()}"
        reason = None
        if self.on_device is False:
            reason = setting
        elif self.on_device == "auto" and device.type == "cpu":
            reason = f"{setting} on a CPU"
        elif getattr(self.trainer, "world_size", 1) > 1:
            reason = f"{getattr(self.trainer, 'world_size', 1)} processes"
        elif size > self.device_budget_gb:
            reason = f"the arrays exceed data.device_budget_gb={self.device_budget_gb:g}"
        if reason is not None:
            log.info("data: batches from the host loader (%s; %.2f GiB of frames and flow)", reason, size)
            return {}
        log.info("data: batches gathered on %s from %.2f GiB of frames and flow kept there (%s)",
                 device, size, setting)  # fmt: skip
        return {s: self._resident_split(s, device) for s in splits}

    def _arrays(self, split: str) -> tuple[list[np.ndarray], dict[int, list[np.ndarray]] | None]:
        """The split's frames and flow arrays (memory maps), per sequence."""
        dataset = self.datasets[split]
        return dataset.frames, (dataset.flow if dataset.flow_files is not None else None)

    def _resident_split(self, split: str, device: torch.device) -> resident.ResidentWindows:
        data = self.datasets[split]
        frames, flow = self._arrays(split)
        return resident.ResidentWindows(data.index, frames, data.targets, data.intrinsics, flow, device)

    # -- loaders --------------------------------------------------------------------------------------

    def _loader(self, split: str, sampler: Sampler | None = None) -> DataLoader:
        return DataLoader(
            self.datasets[split], batch_size=self.batch_size, sampler=sampler, num_workers=self.num_workers,
            pin_memory=self.pin_memory, persistent_workers=self.num_workers > 0, generator=_own_stream(),
        )  # fmt: skip

    def _batches(self, split: str, batches: BatchSampler) -> DataLoader:
        """The split's windows in the given batches: items of the host loader, or index batches that
        :meth:`on_after_batch_transfer` gathers on the device (:mod:`lossvo.data.resident`)."""
        windows = self.resident_windows(split)
        if windows is None:
            return DataLoader(self.datasets[split], batch_sampler=batches, num_workers=self.num_workers,
                              pin_memory=self.pin_memory, persistent_workers=self.num_workers > 0,
                              generator=_own_stream())  # fmt: skip
        return DataLoader(resident.IndexBatches(windows, split), batch_sampler=batches,
                          collate_fn=resident.as_is, generator=_own_stream())  # fmt: skip

    def _tiled_loader(self, split: str) -> DataLoader:
        """Validation or test windows in order, batched by length (a sequence's last may be shorter)."""
        dataset = self.datasets[split]
        batches = windows.SameLengthBatches(
            SequentialSampler(dataset), self.batch_size, lengths=dataset.lengths.tolist()
        )
        return self._batches(split, batches)

    def train_dataloader(self) -> DataLoader:
        """Shuffled training windows; with ``windows_per_epoch``, a fresh random subset every epoch.

        Each epoch's order comes from a generator of its own, seeded with torch's initial seed (the run's
        ``seed``) and the epoch (:class:`EpochShuffle`), so it depends on the seed, the epoch and the data
        alone: not on the network, its head or the loss, which draw from other streams, and a resumed run
        sees the order an uninterrupted one would. Host loader and device gathering give the same batches."""
        dataset = self.datasets["train"]
        count = min(self.windows_per_epoch or len(dataset), len(dataset))
        order = EpochShuffle(len(dataset), count, torch.initial_seed())
        if self.resident_windows("train") is None:
            return self._loader("train", order)
        return self._batches("train", BatchSampler(order, self.batch_size, drop_last=False))

    def val_dataloader(self) -> DataLoader:
        return self._tiled_loader("val")

    def test_dataloader(self) -> DataLoader:
        return self._tiled_loader("test")

    # -- whole sequences (evaluation) -----------------------------------------------------------------

    def normalize(self, frames: torch.Tensor) -> torch.Tensor:
        """uint8 frames (..., 3, H, W) -> float32 ``(x / 255 - mean) / std``, per channel."""
        mean = torch.as_tensor(self.mean, dtype=torch.float32, device=frames.device).view(3, 1, 1)
        std = torch.as_tensor(self.std, dtype=torch.float32, device=frames.device).view(3, 1, 1)
        return frames.float().mul_(1.0 / (255.0 * std)).sub_(mean / std)  # in place: one pass less

    def prepare(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Loaded inputs, on their device, as a network reads them: frames normalised (:meth:`normalize`),
        flow as float32; the other entries as they are."""
        prepared = {**inputs, "frames": self.normalize(inputs["frames"])}
        if "flow" in inputs:
            prepared["flow"] = inputs["flow"].float()
        return prepared

    def on_after_batch_transfer(
        self, batch: dict[str, torch.Tensor], dataloader_idx: int
    ) -> dict[str, torch.Tensor]:
        """On the training device: :meth:`prepare`; when training, windows first stopped
        (``standstill``: no flow), zoomed (``zoom``: the flow and K too), mirrored (``mirror``: the flow and
        K too), played backwards (``reverse``) and jittered (``augment``)."""
        if "frame_index" in batch:  # an index batch of windows kept on the device
            windows = self.resident_windows(str(batch["split"]))
            assert windows is not None
            batch = windows.gather(batch)
        batch = dict(batch)
        frames, targets = batch["frames"], batch["targets"]
        training = self.trainer is not None and self.trainer.training
        if training and self.standstill > 0:
            which = torch.rand(frames.shape[0]) < self.standstill
            frames, targets = standing_windows(frames, targets, which)
            if "flow" in batch:
                moving = ~which.to(frames.device, non_blocking=True)
                batch["flow"] = batch["flow"] * moving.view(-1, 1, 1, 1, 1)
        if training and self.zoom > 1:
            batch = zoomed_windows({**batch, "frames": frames}, self.zoom)
            frames = batch["frames"]
        if training and self.mirror > 0:
            which = torch.rand(frames.shape[0]) < self.mirror
            frames, targets = mirror_windows(frames, targets, which)
            where = which.to(frames.device, non_blocking=True)
            if "flow" in batch:
                mirrored = optical_flow.mirror_flow(batch["flow"])
                batch["flow"] = torch.where(where.view(-1, 1, 1, 1, 1), mirrored, batch["flow"])
            mirrored_K = camera.mirrored_intrinsics(batch["K"], self.width)
            batch["K"] = torch.where(where.view(-1, 1, 1), mirrored_K, batch["K"])
        if training and self.reverse > 0:
            frames, targets = reverse_windows(frames, targets, torch.rand(frames.shape[0]) < self.reverse)
        if training and self.augment:
            frames = jitter(frames.float()).round()
        return self.prepare({**batch, "frames": frames, "targets": targets})

    def sequence_inputs(self, name: str) -> dict[str, np.ndarray]:
        """A whole sequence's inputs: ``frames`` (N, 3, H, W) uint8 (memory map), ``K`` (3, 3) float32 and,
        with flow, ``flow`` (N - 1, 2, H, W) float16 (memory map), each consecutive pair's."""
        inputs = {"frames": self.sequence_frames(name), "K": self.intrinsics(name).astype(np.float32)}
        if self.flow.enabled:
            inputs["flow"] = np.load(self._flow_file(name, 1), mmap_mode="r")
        return inputs

    def sequence_frames(self, name: str) -> np.ndarray:
        """(N, 3, H, W) uint8 RGB cached frames of one sequence (memory map; every frame, in order)."""
        self.setup()
        return np.load(self._frame_files(name)[0], mmap_mode="r")

    def sequence_poses(self, name: str) -> np.ndarray | None:
        """(N, 4, 4) float64 ground-truth camera-to-world poses of one sequence (None without a pose file)."""
        self.setup()
        return self.sequences[name].poses

    def sequence_times(self, name: str) -> np.ndarray:
        """(N,) float64 timestamps (s) of one sequence's frames."""
        self.setup()
        return self.sequences[name].times


class KittiDataModule(VODataModule):
    """KITTI odometry (``data=kitti``): :class:`VODataModule` in its default layout, ``kitti``."""


DATASET_KEYS = ("layout", "root", "train", "val", "test", "unseen", "keep_every", "camera")
"""What an entry of :class:`MultiDataModule`'s ``datasets`` may set."""
DERIVED = ("root", "layout", "train", "val", "test", "unseen", "keep_every", "camera")
""":class:`VODataModule` arguments that :class:`MultiDataModule` derives from its ``datasets``."""


def _dataset_entries(datasets: Any) -> dict[str, dict[str, Any]]:
    """``data.datasets`` checked: a mapping of keys (no ``/``) to entries with a ``layout`` and a ``root`` and
    only :data:`DATASET_KEYS`; ValueError naming the key otherwise."""
    if not isinstance(datasets, Mapping) or not datasets:
        raise ValueError(f"data.datasets: expected a mapping of names to datasets, got {datasets!r}")
    entries = {}
    for key, entry in datasets.items():
        where = f"data.datasets.{key}"
        if not isinstance(key, str) or not key or "/" in key:
            raise ValueError(f"data.datasets: expected names without '/', got {key!r}")
        if not isinstance(entry, Mapping):
            raise ValueError(f"{where}: expected {{layout: ..., root: ..., train: [...]}}, got {entry!r}")
        unknown = sorted(set(entry) - set(DATASET_KEYS))
        if unknown:
            raise ValueError(
                f"{where}.{unknown[0]}: unknown key (expected some of {', '.join(DATASET_KEYS)})"
            )
        for required in ("layout", "root"):
            if entry.get(required) is None:
                raise ValueError(f"{where}.{required}: a value is required")
        layouts.check_layout(entry["layout"], f"{where}.layout")
        every = entry.get("keep_every", 1)
        if not is_integer(every, 1):
            raise ValueError(f"{where}.keep_every: expected an integer >= 1 (frames), got {every!r}")
        entries[key] = dict(entry)
    return entries


class MultiDataModule(VODataModule):
    """Several datasets in one run: windows from each (each with its own K), one normalisation pooled over
    every training sequence, and the sequences of each evaluated.

    Args:
        datasets: name -> ``{layout, root, train, val, test, unseen, keep_every}``, each as
            :class:`VODataModule` takes it; the run's sequences are named ``<name>/<sequence>``
            (``tum/rgbd_dataset_freiburg1_xyz``).
        Other arguments as :class:`VODataModule` (frame size, windows, loader, flow), shared by the datasets.
    """

    def __init__(self, datasets: Mapping[str, Mapping[str, Any]], **kwargs: Any) -> None:
        entries = _dataset_entries(datasets)
        shared = {k: v for k, v in kwargs.items() if k not in DERIVED}
        train, val, test, unseen = (
            [f"{key}/{name}" for key, e in entries.items()
             for name in _names(e.get(split) or [], f"datasets.{key}.{split}")]
            for split in ("train", "val", "test", "unseen")
        )  # fmt: skip
        first = next(iter(entries.values()))
        super().__init__(str(first["root"]), train, val, test, unseen, layout=first["layout"], **shared)
        self.sources = {
            key: Source(
                e["layout"],
                Path(e["root"]).expanduser(),
                int(e.get("keep_every", 1)),
                _camera(e.get("camera"), f"data.datasets.{key}.camera"),
            )
            for key, e in entries.items()
        }
        self.layout = "multi"

    def description(self) -> dict[str, Any]:
        """:meth:`VODataModule.description` with ``layout`` ``multi``, the run's ``train`` names and the
        ``datasets``, without the arguments derived from them."""
        described = super().description()
        dropped = set(DERIVED) - {"train", "layout"}
        return {k: v for k, v in described.items() if k not in dropped} | {"layout": "multi"}


class SyntheticDataModule(VODataModule):
    """The embedded synthetic KITTI-layout dataset, rendered into ``root`` on first use.

    Args:
        root: where the dataset is (or will be) written; default ``<cache_dir>/synthetic``.
        frames: frames per sequence (None: the generator's defaults).
        render_height, render_width: resolution the generator writes (None: its default).
        seed: the generator's seed (a different seed is a different set of worlds and routes).
        route_families: route families added or changed, name -> parameters of
            :class:`lossvo.data.synthetic.routes.Family` (None: the built-in ones).
        route_mixes: sequence -> {family: weight} for the sequences whose routes differ from the
            built-in mixes (None: none).
        Other arguments as :class:`KittiDataModule`.
    """

    def __init__(self, root: str | None = None, frames: int | dict[str, int] | None = None,
                 render_height: int | None = None, render_width: int | None = None,
                 seed: int = 0, route_families: Mapping | None = None, route_mixes: Mapping | None = None,
                 **kwargs) -> None:  # fmt: skip
        cache_dir = kwargs.get("cache_dir")
        base = Path(cache_dir).expanduser() if cache_dir else frame_cache.default_cache_dir()
        super().__init__(root=str(root or base / "synthetic"), **kwargs)
        spec = routes.route_spec(route_families, route_mixes, prefix="data.")
        self.generator_args: dict[str, Any] = {  # synthetic.ensure_dataset's keyword arguments
            "frames": dict(frames) if isinstance(frames, Mapping) else frames,
            "height": render_height or synthetic.DEFAULT_HEIGHT,
            "width": render_width or synthetic.DEFAULT_WIDTH, "seed": seed, "spec": spec,
        }  # fmt: skip

    def _ensure_rendered(self) -> None:
        """Render the dataset unless it is there; the lock lets parallel sweep jobs share it."""
        self.root.mkdir(parents=True, exist_ok=True)
        with FileLock(self.root.parent / f".{self.root.name}.lock"):
            synthetic.ensure_dataset(self.root, sequences=self.all_names, **self.generator_args)

    def load_metadata(self) -> None:
        self._ensure_rendered()
        super().load_metadata()

    def prepare_data(self) -> None:
        self._ensure_rendered()
        super().prepare_data()

    def setup(self, stage: str | None = None) -> None:
        if not self.datasets:
            self._ensure_rendered()
        super().setup(stage)
