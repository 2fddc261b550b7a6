"""PNG encoding of rendered frames: fast settings, the same bytes for the same pixels."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.10: one fixed filter, not chosen per row
    PNG_PARAMS += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH]


def write_png(path: Path, image: np.ndarray) -> None:
    """Write image ((H, W, 3) BGR or (H, W) grey uint8) to path as a PNG."""
    encoded, png = cv2.imencode(".png", image, PNG_PARAMS)
    if not encoded:
        raise RuntimeError(f"OpenCV could not encode {path}")
    path.write_bytes(png.tobytes())
