"""The pinhole camera of the cached frames: intrinsics after resizing, and the intrinsics layer.

Pixel coordinates are those of OpenCV and KITTI's P2: ``(0, 0)`` is the centre of the top-left pixel, x to
the right, y down.
"""

from __future__ import annotations

import numpy as np
import torch


def resized_intrinsics(K: np.ndarray, source_hw: tuple[int, int], target_hw: tuple[int, int]) -> np.ndarray:
    """K (3, 3) of frames resized from ``source_hw`` to ``target_hw`` (H, W) pixels, as ``cv2.resize``
    maps pixel centres: ``fx' = fx W' / W``, ``cx' = (cx + 0.5) W' / W - 0.5`` (likewise in y); float64."""
    sy, sx = target_hw[0] / source_hw[0], target_hw[1] / source_hw[1]
    K = np.asarray(K, dtype=np.float64) / K[2, 2]
    return np.array(
        [
            [K[0, 0] * sx, K[0, 1] * sx, (K[0, 2] + 0.5) * sx - 0.5],
            [0.0, K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5],
            [0.0, 0.0, 1.0],
        ]
    )


def mirrored_intrinsics(K: torch.Tensor, width: int) -> torch.Tensor:
    """K (..., 3, 3) of frames mirrored left to right: the principal point at ``width - 1 - cx``."""
    mirrored = K.clone()
    mirrored[..., 0, 2] = width - 1 - K[..., 0, 2]
    return mirrored


def intrinsics_channels(K: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """The intrinsics layer (TartanVO), K (..., 3, 3) -> (..., 2, height, width) in K's dtype: every
    pixel's ``(x - cx) / fx`` and ``(y - cy) / fy``, so a network can turn pixel displacements into angles."""
    x = torch.arange(width, dtype=K.dtype, device=K.device)
    y = torch.arange(height, dtype=K.dtype, device=K.device)
    fx, fy, cx, cy = (K[..., i, j, None, None] for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    u = ((x - cx) / fx).expand(*K.shape[:-2], height, width)
    v = ((y[:, None] - cy) / fy).expand(*K.shape[:-2], height, width)
    return torch.stack((u, v), dim=-3)
