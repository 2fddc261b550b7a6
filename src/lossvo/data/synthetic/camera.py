"""The camera: KITTI's left colour camera scaled to the rendered size, or one drawn per sequence
(:class:`CameraRange`), and the calib.txt that describes it; KITTI's axes, pixel centres at integers."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from lossvo.console import UserError
from lossvo.geometry.camera import resized_intrinsics

KITTI_SIZE = (376, 1241)
"""(height, width) in pixels of KITTI odometry colour images."""
KITTI_INTRINSICS = (718.856, 718.856, 607.1928, 185.2157)
"""(fx, fy, cx, cy) in pixels of KITTI's P2 at KITTI_SIZE (sequences 00-02)."""
CAMERA_HEIGHT = 1.65
"""Metres from the camera centre down to the ground (the world plane y = +1.65)."""


def intrinsics(height: int, width: int) -> np.ndarray:
    """(3, 3) float64 K: KITTI's P2 intrinsics scaled to (height, width) pixels as a resize scales them."""
    fx, fy, cx, cy = KITTI_INTRINSICS
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return resized_intrinsics(K, KITTI_SIZE, (height, width))


@dataclass(frozen=True)
class CameraRange:
    """Ranges (low, high) a sequence's camera is drawn from, uniformly: ``focal``, fx as a fraction of the
    width; ``principal``, (cx, cy) as fractions of width and height; ``aspect``, fy / fx (docs/data.md)."""

    focal: tuple[float, float] = (0.45, 0.85)
    principal: tuple[float, float] = (0.45, 0.55)
    aspect: tuple[float, float] = (0.95, 1.05)

    @classmethod
    def of(cls, value: Any, where: str) -> CameraRange:
        """From ``{focal: [lo, hi], principal: [lo, hi], aspect: [lo, hi]}`` (each optional); UserError
        naming ``<where>.<key>`` for a range that cannot be rendered."""
        if not isinstance(value, Mapping):
            raise UserError(f"{where}: expected {{focal: [lo, hi], principal: [lo, hi], aspect: [lo, hi]}}, "
                            f"got {value!r}")  # fmt: skip
        unknown = sorted(set(map(str, value)) - set(asdict(cls())))
        if unknown:
            raise UserError(f"{where}.{unknown[0]}: unknown key (expected some of focal, principal, aspect)")
        ranges = {key: _range(v, f"{where}.{key}") for key, v in {**asdict(cls()), **value}.items()}
        for key in ("focal", "aspect"):
            if ranges[key][0] <= 0:
                raise UserError(f"{where}.{key}: expected values > 0, got {list(ranges[key])}")
        if not (ranges["principal"][0] > 0 and ranges["principal"][1] < 1):
            raise UserError(f"{where}.principal: expected fractions of the frame inside (0, 1), "
                            f"got {list(ranges['principal'])}")  # fmt: skip
        return cls(**ranges)

    def draw(self, height: int, width: int, seed: int, sequence: str) -> np.ndarray:
        """(3, 3) float64 K of a sequence's frames of (height, width) pixels, drawn from the ranges with a
        stream of its own (the town and the route do not change with the ranges)."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, int(sequence), 7919]))
        focal, cx, cy, aspect = (
            rng.uniform(*r) for r in (self.focal, self.principal, self.principal, self.aspect)
        )
        fx = focal * width
        return np.array([[fx, 0.0, cx * width], [0.0, fx * aspect, cy * height], [0.0, 0.0, 1.0]])

    def manifest(self) -> dict[str, list[float]]:
        """The ranges as a manifest records them."""
        return {key: list(value) for key, value in asdict(self).items()}


def _range(value: Any, key: str) -> tuple[float, float]:
    """``[lo, hi]`` as floats; UserError naming ``key`` unless two finite numbers with lo <= hi."""
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise UserError(f"{key}: expected a range [low, high] of two numbers, got {value!r}") from None
    if not (math.isfinite(low) and math.isfinite(high)) or low > high:
        raise UserError(f"{key}: expected a range [low, high] with low <= high, got {value!r}")
    return low, high


def calib_text(K: np.ndarray) -> str:
    """KITTI calib.txt content for intrinsics K (3, 3): P0..P3 = K [I | t_i] (the rendered camera is 2,
    the others at KITTI's offsets) and Tr, KITTI's nominal velodyne-to-camera axis swap."""
    offsets = {"P0": -0.06, "P1": -0.60, "P2": 0.0, "P3": -0.533}
    rows = {name: K @ np.hstack([np.eye(3), [[tx], [0.0], [0.0]]]) for name, tx in offsets.items()}
    rows["Tr"] = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27]])
    return "".join(f"{name}: " + " ".join(f"{v:.12e}" for v in P.ravel()) + "\n" for name, P in rows.items())
