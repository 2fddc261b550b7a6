"""The pinhole camera of the cached frames: intrinsics after resizing, and the intrinsics layer.

Pixel coordinates are those of OpenCV and KITTI's P2: ``(0, 0)`` is the centre of the top-left pixel, x to
the right, y down.
"""

from __future__ import annotations

import numpy as np
import torch


def resized_intrinsics(K: np.ndarray, source_hw: tuple[int, int], target_hw: tuple[int, int]) -> np.ndarray:
    """K of frames resized from ``source_hw`` to ``target_hw`` (H, W) pixels, as ``cv2.resize`` maps
    them: a pixel centre x goes to ``(x + 0.5) * W' / W - 0.5``, so ``fx' = fx W' / W`` and
    ``cx' = (cx + 0.5) W' / W - 0.5`` (likewise in y).

    Args:
        K: (3, 3) intrinsics in pixels of the source frames.
    Returns:
        (3, 3) float64.
    """
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
    """K of frames mirrored left to right: the principal point at ``W - 1 - cx``.

    Args:
        K: (..., 3, 3); width: W in pixels.
    Returns:
        (..., 3, 3).
    """
    mirrored = K.clone()
    mirrored[..., 0, 2] = width - 1 - K[..., 0, 2]
    return mirrored


def intrinsics_channels(K: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """The intrinsics layer (TartanVO): every pixel's normalised image coordinates, ``(x - cx) / fx`` and
    ``(y - cy) / fy``, as two channels, so that a network can turn pixel displacements into angles.

    Args:
        K: (..., 3, 3) intrinsics in pixels of frames of ``height`` x ``width``.
    Returns:
        (..., 2, height, width), K's dtype.
    """
    x = torch.arange(width, dtype=K.dtype, device=K.device)
    y = torch.arange(height, dtype=K.dtype, device=K.device)
    fx, fy, cx, cy = (K[..., i, j, None, None] for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    u = ((x - cx) / fx).expand(*K.shape[:-2], height, width)
    v = ((y[:, None] - cy) / fy).expand(*K.shape[:-2], height, width)
    return torch.stack((u, v), dim=-3)
