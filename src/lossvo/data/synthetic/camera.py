"""The camera: KITTI's left colour camera (image_2) scaled to the rendered size, mounted CAMERA_HEIGHT
above the ground, and the calib.txt that describes it.

Axes are KITTI's: x right, y down, z forward; K maps camera coordinates to pixels with pixel centres at
integer coordinates.
"""

from __future__ import annotations

import numpy as np

from lossvo.geometry.camera import resized_intrinsics

KITTI_SIZE = (376, 1241)
"""(height, width) in pixels of KITTI odometry colour images."""
KITTI_INTRINSICS = (718.856, 718.856, 607.1928, 185.2157)
"""(fx, fy, cx, cy) in pixels of KITTI's P2 at KITTI_SIZE (sequences 00-02)."""

CAMERA_HEIGHT = 1.65
"""Metres from the camera centre down to the ground at frame 0; the ground is the world plane y = +1.65."""


def intrinsics(height: int, width: int) -> np.ndarray:
    """KITTI's P2 intrinsics scaled to (height, width) pixels, as resizing a KITTI frame scales them
    (:func:`lossvo.geometry.camera.resized_intrinsics`): (3, 3) float64 K."""
    fx, fy, cx, cy = KITTI_INTRINSICS
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return resized_intrinsics(K, KITTI_SIZE, (height, width))


def calib_text(K: np.ndarray) -> str:
    """KITTI calib.txt content for intrinsics K (3, 3): P0..P3 = K [I | t_i], Tr, 12 floats each.

    The rendered camera is camera 2, so P2 = [K | 0]; the others sit at KITTI's offsets to its right
    (grey cameras 0 and 1 at 0.06 m and 0.60 m, colour camera 3 at 0.53 m); Tr is KITTI's nominal
    velodyne-to-camera axis swap.
    """
    offsets = {"P0": -0.06, "P1": -0.60, "P2": 0.0, "P3": -0.533}
    lines = []
    for name, tx in offsets.items():
        P = K @ np.hstack([np.eye(3), [[tx], [0.0], [0.0]]])
        lines.append(f"{name}: " + " ".join(f"{v:.12e}" for v in P.ravel()))
    velo_to_cam = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27]])
    lines.append("Tr: " + " ".join(f"{v:.12e}" for v in velo_to_cam.ravel()))
    return "\n".join(lines) + "\n"
