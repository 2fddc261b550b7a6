"""The dataset layouts lossvo reads, by name (``data.sources.<name>.layout``): where a layout's name becomes
its reader, a module returning :class:`lossvo.data.sequence.Sequence` (docs/data.md).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from types import ModuleType

import numpy as np

from lossvo.console import UserError
from lossvo.data import euroc, kitti, mimir, tartanair, tum
from lossvo.data.sequence import Sequence

READERS: dict[str, ModuleType] = {
    "kitti": kitti,
    "tum": tum,
    "euroc": euroc,
    "tartanair": tartanair,
    "mimir": mimir,
}
"""Each layout's reader: ``load_sequence(root, name, require_poses)``, ``list_sequences(root)``."""
LAYOUTS = tuple(READERS)
METRIC_SCALE_LAYOUTS = ("kitti",)
"""Layouts whose platform gives monocular metric scale a cue (a car's camera at a known height above a road):
their translation is read as the metric RPE, the others' as the scale-given one."""
ASSUMED_RATE_HZ = {"tartanair": tartanair.RATE_HZ}
"""Layouts without timestamps and the frame rate (Hz) their reader assumes."""


def check_layout(layout: object, key: str = "layout") -> str:
    """``layout`` if it names a layout; UserError naming ``key`` and the layouts otherwise."""
    if layout not in READERS:
        raise UserError(f"{key}: unknown dataset layout {layout!r} (expected one of {', '.join(LAYOUTS)})")
    return str(layout)


def dataset_root(layout: str, root: str | os.PathLike) -> Path:
    """The folder a layout's reader takes: ``root``, or for KITTI :func:`lossvo.data.kitti.find_root`'s."""
    if check_layout(layout) == "kitti":
        return kitti.find_root(root)
    return Path(root).expanduser()


def load_sequence(
    layout: str,
    root: Path,
    name: str,
    require_poses: bool = True,
    camera: tuple[np.ndarray, np.ndarray] | None = None,
) -> Sequence:
    """One sequence of the dataset at ``root`` (:func:`dataset_root`), read by its layout's reader;
    ``camera`` (K (3, 3) pixels, distortion) replaces the reader's, and the TUM reader, which otherwise
    takes the camera from the sequence's name, is given it."""
    reader = READERS[check_layout(layout)]
    given = {"K": camera[0], "distortion": camera[1]} if camera is not None and reader is tum else {}
    seq = reader.load_sequence(root, name, require_poses=require_poses, **given)
    return seq if camera is None else dataclasses.replace(seq, K=camera[0], distortion=camera[1])


def list_sequences(layout: str, root: Path) -> list[str]:
    """Names of the sequences of the dataset at ``root`` (:func:`dataset_root`), sorted."""
    return list(READERS[check_layout(layout)].list_sequences(root))
