"""Optical flow between cached frames: OpenCV's DIS (medium preset), cached once per sequence and frame step
as float16 (N - s, 2, H, W) ``(u, v)`` in pixels of the cached frames (:mod:`lossvo.data.array_cache`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from lossvo.checks import is_number
from lossvo.console import UserError
from lossvo.data import array_cache, frame_cache

FLOW_VERSION = 1
METHODS = ("dis", "none")
MAX_SCALE = 4.0
"""Largest ``scale``: finer frames cost DIS time in proportion to their pixels."""
CHUNK = 64
"""Pairs computed together: the frames a chunk needs are read once, then dropped."""
WORKERS = 2


@dataclass(frozen=True)
class FlowSetting:
    """Which flow a dataset caches: ``method`` one of METHODS; ``scale``: computed on the source images at
    ``scale`` times the cached size, then resized (DIS resolves small motions better on finer frames)."""

    method: str = "dis"
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise UserError(f"data.flow.method: expected one of {', '.join(METHODS)}, got {self.method!r}")
        if not is_number(self.scale) or not 1.0 <= self.scale <= MAX_SCALE:
            raise UserError(f"data.flow.scale: expected a number in [1, {MAX_SCALE:g}], got {self.scale!r}")

    @property
    def enabled(self) -> bool:
        return self.method != "none"

    @property
    def key(self) -> str:
        """The setting in file names and manifests: ``"dis-medium"``, ``"dis-medium-x1.5"``."""
        return "dis-medium" if self.scale == 1 else f"dis-medium-x{self.scale:g}"


def _gray(frame: np.ndarray) -> np.ndarray:
    """(3, H, W) uint8 RGB -> (H, W) uint8 grey, contiguous (what OpenCV's flows take)."""
    return cv2.cvtColor(np.ascontiguousarray(frame.transpose(1, 2, 0)), cv2.COLOR_RGB2GRAY)


class _Estimator(threading.local):
    """One flow estimator per thread (OpenCV's DIS object keeps state between calls)."""

    def __init__(self) -> None:  # in each thread that uses it
        self.dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)

    def __call__(self, first: np.ndarray, second: np.ndarray) -> np.ndarray:
        """(2, H, W) float32 flow from ``first`` to ``second``, both (H, W) uint8 grey."""
        flow = self.dis.calc(first, second, None)  # type: ignore[call-overload]  # None: OpenCV allocates it
        return flow.transpose(2, 0, 1)


def pair_flow(first: np.ndarray, second: np.ndarray, setting: FlowSetting = FlowSetting()) -> np.ndarray:
    """(2, H, W) float32 (u, v) in pixels from ``first`` to ``second``, (3, H, W) uint8 RGB frames: pixel
    (x, y) of ``first`` is at (x + u, y + v) in ``second``."""
    if not setting.enabled:
        raise UserError("data.flow.method: none computes no flow")
    return _Estimator()(_gray(first), _gray(second))


def resized_flow(field: np.ndarray, height: int, width: int) -> np.ndarray:
    """A (2, h, w) flow in pixels of (h, w) frames as the flow of the same frames at (height, width): area
    interpolation, u scaled by width / w and v by height / h."""
    h, w = field.shape[1:]
    if (h, w) == (height, width):
        return field
    resized = cv2.resize(field.transpose(1, 2, 0), dsize=(width, height), interpolation=cv2.INTER_AREA)
    return resized.transpose(2, 0, 1) * np.array([width / w, height / h], dtype=np.float32).reshape(2, 1, 1)


def flow_file(folder: Path, name: str, step: int, setting: FlowSetting) -> Path:
    """The flow array of sequence ``name`` at frame step ``step`` in a frame-cache folder."""
    return folder / f"{name}.flow-{setting.key}-s{step}.npy"


def ensure_flow(
    folder: Path,
    name: str,
    frames: np.ndarray,
    frames_source: dict,
    step: int,
    setting: FlowSetting,
    images: Sequence[Path] = (),
    progress: bool = True,
    undistort: frame_cache.Undistortion | None = None,
    crop: bool = False,
) -> np.ndarray:
    """(max(N - step, 0), 2, H, W) float16 cached flow of a sequence's (N, 3, H, W) cached ``frames`` at
    one frame step, computed first where missing or stale (``frames_source``: the frame cache's record of
    them). ``images``, ``undistort``, ``crop``: the source images, read again where ``setting.scale > 1``.
    :data:`CHUNK` pairs at a time on :data:`WORKERS` threads (OpenCV releases the GIL)."""
    n, _, height, width = frames.shape
    if setting.scale != 1 and len(images) != n:
        raise UserError(
            f"data.flow.scale={setting.scale:g} reads the source images: expected {n}, got {len(images)}"
        )
    size = round(height * setting.scale), round(width * setting.scale)  # the frames the flow is computed on

    def read(k: int) -> np.ndarray:
        """Frame k, (h, w) uint8 grey at the size the flow is computed at."""
        if setting.scale == 1:
            return _gray(frames[k])
        return _gray(frame_cache.read_frame(images[k], *size, undistort, crop)[0])

    def fill(out: np.ndarray) -> dict:
        estimate = _Estimator()
        desc = f"flow {name} (step {step}, {setting.key})"  # shown on a terminal only (disable=None)
        with (
            ThreadPoolExecutor(WORKERS) as pool,
            tqdm(None, desc, len(out), leave=False, disable=None if progress else True, unit="pair") as bar,
        ):
            for lo in range(0, len(out), CHUNK):
                hi = min(lo + CHUNK, len(out))
                grey = list(pool.map(read, range(lo, hi + step)))
                fields = pool.map(estimate, grey[: hi - lo], grey[step:])
                for k, field in enumerate(fields, lo):
                    out[k] = resized_flow(field, height, width)
                bar.update(hi - lo)
        return {}

    shape = (max(n - step, 0), 2, height, width)
    expected = {
        "version": FLOW_VERSION,
        "sequence": name,
        "step": step,
        "flow": setting.key,
        "frames": frames_source,
    }
    return array_cache.ensure_array(flow_file(folder, name, step, setting), expected, shape, np.float16, fill)


def mirror_flow(flow: torch.Tensor) -> torch.Tensor:
    """(..., 2, H, W) flow of horizontally mirrored frames: fields flipped left to right, ``u`` negated."""
    sign = torch.tensor([-1.0, 1.0], dtype=flow.dtype).to(flow.device, non_blocking=True).view(2, 1, 1)
    return flow.flip(-1) * sign
