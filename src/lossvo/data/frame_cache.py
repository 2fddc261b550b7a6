"""A sequence's frames decoded once (undistorted, cropped, resized with area interpolation) into one uint8
(N, 3, H, W) RGB ``.npy`` beside a manifest (:mod:`lossvo.data.array_cache`), memory-mapped afterwards.
"""

from __future__ import annotations

import hashlib
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from lossvo.data import array_cache
from lossvo.data.kitti import KittiFormatError, check_png
from lossvo.data.sequence import Sequence

CACHE_VERSION = 2
WORKERS = 4


def default_cache_dir() -> Path:
    """``$LOSSVO_CACHE`` if set, else ``~/.cache/lossvo``."""
    return Path(os.environ.get("LOSSVO_CACHE", Path.home() / ".cache" / "lossvo")).expanduser()


def cache_folder(cache_dir: str | os.PathLike, root: Path, height: int, width: int) -> Path:
    """Folder of one dataset root's frames at one size: ``cache_dir/frames/<root>-<hash>/<H>x<W>``."""
    resolved = str(Path(root).resolve())
    digest = hashlib.sha1(resolved.encode()).hexdigest()[:10]
    return Path(cache_dir) / "frames" / f"{Path(resolved).name}-{digest}" / f"{height}x{width}"


@dataclass(frozen=True)
class Undistortion:
    """How a distorted sequence's frames are undistorted: OpenCV's remap onto a pinhole camera ``K`` (3, 3)
    of the same source size (H, W) (``getOptimalNewCameraMatrix``, ``alpha=0``: no black border)."""

    K: np.ndarray
    size: tuple[int, int]
    map_x: np.ndarray
    map_y: np.ndarray

    def apply(self, image: np.ndarray) -> np.ndarray:
        """(H, W[, C]) uint8 source frame -> the undistorted frame, bilinear."""
        return cv2.remap(image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def undistortion(seq: Sequence) -> Undistortion | None:
    """The :class:`Undistortion` of a sequence's frames; None when its distortion is all zeros."""
    if not np.any(seq.distortion):
        return None
    height, width = seq.size
    K = source_intrinsics(seq)
    map_x, map_y = cv2.initUndistortRectifyMap(seq.K, seq.distortion, None, K, (width, height), cv2.CV_32FC1)
    return Undistortion(K, (height, width), map_x, map_y)


def source_intrinsics(seq: Sequence) -> np.ndarray:
    """(3, 3) float64 K of a sequence's frames before resizing (undistorted where they have distortion)."""
    if not np.any(seq.distortion):
        return seq.K
    height, width = seq.size
    K, _ = cv2.getOptimalNewCameraMatrix(seq.K, seq.distortion, (width, height), 0.0, (width, height))
    return np.asarray(K, dtype=np.float64)


def _fingerprint(seq: Sequence) -> dict:
    """What the cache depends on: frame names, total size, latest mtime and any distortion."""
    stats = [p.stat() for p in seq.images]
    fingerprint = {
        "frames": [p.name for p in seq.images],
        "bytes": sum(s.st_size for s in stats),
        "mtime_ns": max(s.st_mtime_ns for s in stats),
    }
    if np.any(seq.distortion):
        fingerprint["undistorted"] = {"K": seq.K.tolist(), "distortion": seq.distortion.tolist()}
    return fingerprint


def files(folder: Path, name: str) -> tuple[Path, Path]:
    """The frames file (.npy) and the manifest (.json) of sequence ``name`` in a cache folder."""
    return folder / f"{name}.npy", folder / f"{name}.json"


def centre_crop(size_hw: tuple[int, int], target_hw: tuple[int, int]) -> tuple[int, int, int, int]:
    """``(y0, x0, h, w)``: the largest centred window of an (H, W) frame with ``target_hw``'s aspect ratio."""
    H, W = size_hw
    th, tw = target_hw
    if W * th > H * tw:  # wider than the target: keep the full height
        w = min(W, max(1, round(H * tw / th)))
        return 0, (W - w) // 2, H, w
    h = min(H, max(1, round(W * th / tw)))
    return (H - h) // 2, 0, h, W


def cropped_intrinsics(K: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """(3, 3) K of the window ``box`` = (y0, x0, h, w) of a frame: the principal point moved by (x0, y0)."""
    out = np.array(K, dtype=np.float64)
    out[:2, 2] -= (box[1], box[0])
    return out


def read_frame(
    path: Path, height: int, width: int, undistort: Undistortion | None = None, crop: bool = False
) -> tuple[np.ndarray, tuple[int, int]]:
    """One PNG decoded, undistorted (where it has ``undistort``'s size), cropped and resized: (3, height,
    width) RGB uint8, and the PNG's own size (H, W)."""
    check_png(path)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise KittiFormatError(f"{path}: unreadable image (OpenCV could not decode it)")
    size = image.shape[:2]
    if undistort is not None and size == undistort.size:
        image = undistort.apply(image)
    if crop:
        y0, x0, h, w = centre_crop(size, (height, width))
        image = image[y0 : y0 + h, x0 : x0 + w]
    # OpenCV sizes are (width, height); the swap is a classic bug, hence the explicit names.
    resized = cv2.resize(image, dsize=(width, height), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(resized, cv2.COLOR_BGR2RGB).transpose(2, 0, 1), size


def ensure_frames(folder: Path, seq: Sequence, height: int, width: int, crop: bool = False) -> np.ndarray:
    """The cached frames of ``seq``, built first where missing, incomplete or stale (decoded on
    :data:`WORKERS` threads: OpenCV releases the GIL); KittiFormatError for frames of two sizes."""
    undistort = undistortion(seq)

    def fill(out: np.ndarray) -> dict:
        first_size: tuple[int, int] | None = None
        with ThreadPoolExecutor(WORKERS) as pool:
            jobs = pool.map(lambda p: read_frame(p, height, width, undistort, crop), seq.images)
            desc = f"caching {seq.name} at {height}x{width}"  # shown on a terminal only (disable=None)
            bar = tqdm(jobs, desc, len(seq.images), leave=False, disable=None, unit="frame")
            for i, (frame, size) in enumerate(bar):
                first_size = first_size or size
                if size != first_size:
                    raise KittiFormatError(
                        f"{seq.images[i]}: image is {size[1]}x{size[0]} (WxH) but the sequence's first "
                        f"frame is {first_size[1]}x{first_size[0]}: expected one size per sequence"
                    )
                out[i] = frame
        assert first_size is not None  # a Sequence has frames (kitti.image_paths raises on none)
        return {"source_size_hw": list(first_size)}

    expected = {"version": CACHE_VERSION, "sequence": seq.name, "source": _fingerprint(seq)}
    if crop:
        expected["crop"] = "centre"
    shape = (len(seq.images), 3, height, width)
    return array_cache.ensure_array(files(folder, seq.name)[0], expected, shape, np.uint8, fill)


def channel_stats(frames: list[np.ndarray], chunk: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """(3,) mean and (3,) std of uint8 (N_i, 3, H, W) frames in [0, 1] units, ``chunk`` frames at a time."""
    total, total_sq, count = np.zeros(3), np.zeros(3), 0
    for array in frames:
        for start in range(0, len(array), chunk):
            block = np.asarray(array[start : start + chunk], dtype=np.float64) / 255.0
            total += block.sum(axis=(0, 2, 3))
            total_sq += np.square(block).sum(axis=(0, 2, 3))
            count += block.size // 3
    mean = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean**2, 0.0))
    return mean, np.maximum(std, 1e-6)
