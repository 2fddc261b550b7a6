"""One cached array: an ``.npy`` file beside a JSON manifest that is written last.

The manifest says what the array was built from. An array is read (memory-mapped) only when its manifest
exists, matches what the caller expects and the file has the expected shape and dtype: a cache from an
interrupted run, a truncated file or changed inputs is rebuilt, never read as garbage. A file lock lets
the jobs of a parallel sweep that share a cache build each array once.
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
"""Writes every element of the (memory-mapped) array it is given; returns manifest entries it found
while doing so (for example the size of the source images)."""


def manifest_of(data: Path) -> Path:
    """The manifest beside an array file: ``x.npy`` -> ``x.json``."""
    return data.with_suffix(".json")


def open_array(
    data: Path, expected: dict[str, Any], shape: tuple[int, ...], dtype: np.dtype | type, say: bool = True
) -> np.ndarray | None:
    """The array in ``data`` as a read-only memory map, or None if it is missing, incomplete or stale:
    its manifest must hold every entry of ``expected`` with the same value, and the array ``shape`` and
    ``dtype``. ``say``: a warning names an unreadable or stale array."""
    manifest = manifest_of(data)
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


def build_array(
    data: Path, expected: dict[str, Any], shape: tuple[int, ...], dtype: np.dtype | type, fill: Fill
) -> np.ndarray:
    """Write the array ``fill`` computes into ``data`` (through a temporary file), then its manifest
    (``expected``, the shape and what ``fill`` returned); the memory map. An exception leaves no array
    that looks complete."""
    data.parent.mkdir(parents=True, exist_ok=True)
    manifest = manifest_of(data)
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


def ensure_array(
    data: Path, expected: dict[str, Any], shape: tuple[int, ...], dtype: np.dtype | type, fill: Fill
) -> np.ndarray:
    """The array in ``data`` (:func:`open_array`), built first by :func:`build_array` where it is missing,
    incomplete or stale, under a file lock so that concurrent jobs build it once."""
    array = open_array(data, expected, shape, dtype)
    if array is not None:
        return array
    data.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(data.parent / f".{data.stem}.lock"):
        array = open_array(data, expected, shape, dtype, say=False)  # another job may have built it
        if array is None:
            array = build_array(data, expected, shape, dtype, fill)
    return array
