"""One cached array: an ``.npy`` file beside a JSON manifest, written last, of what it was built from; read
only when both match what the caller expects, built once under a file lock otherwise.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from filelock import FileLock

from lossvo.atomic import write_text_atomic

log = logging.getLogger(__name__)

Fill = Callable[[np.ndarray], dict[str, Any]]
"""Writes every element of the array it is given; returns manifest entries it found on the way."""


def open_array(
    data: Path, expected: dict[str, Any], shape: tuple[int, ...], dtype: np.dtype | type, say: bool = True
) -> np.ndarray | None:
    """The array in ``data`` as a read-only memory map, or None if missing or stale (``say``: warn)."""
    manifest = data.with_suffix(".json")
    try:
        meta = json.loads(manifest.read_text())
        array = np.load(data, mmap_mode="r")
    except (OSError, ValueError) as e:
        if say and (manifest.exists() or data.exists()):
            log.warning("cache %s is unreadable (%s): rebuilding", data, e)
        return None
    current = isinstance(meta, dict) and all(meta.get(key) == value for key, value in expected.items())
    if not current or array.shape != shape or array.dtype != np.dtype(dtype):
        if say:
            log.warning("cache %s is stale or incomplete: rebuilding", data)
        return None
    return array


def ensure_array(
    data: Path, expected: dict[str, Any], shape: tuple[int, ...], dtype: np.dtype | type, fill: Fill
) -> np.ndarray:
    """The array in ``data``, built first where it is missing, incomplete or stale (once, under a lock):
    ``fill`` writes it into a temporary file, then the manifest is written."""
    array = open_array(data, expected, shape, dtype)
    if array is not None:
        return array
    data.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(data.parent / f".{data.stem}.lock"):
        array = open_array(data, expected, shape, dtype, say=False)  # another job may have built it
        if array is not None:
            return array
        manifest = data.with_suffix(".json")
        manifest.unlink(missing_ok=True)  # the manifest marks a complete array; none while writing
        tmp = data.with_name(f".{data.name}.{os.getpid()}.tmp")
        start = time.perf_counter()
        out = np.lib.format.open_memmap(tmp, mode="w+", dtype=dtype, shape=shape)
        try:
            found = fill(out)
            out.flush()
            del out
            os.replace(tmp, data)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        write_text_atomic(manifest, json.dumps({**expected, "shape": list(shape), **found}))
        log.info("cache %s: built in %.1f s", data, time.perf_counter() - start)
        return np.load(data, mmap_mode="r")
