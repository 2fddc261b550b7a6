"""Writing datasets: each sequence rendered into the KITTI odometry layout and moved into place whole,
sequences in parallel processes, the manifest last; :func:`generate` and :func:`ensure_dataset`.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import sys
import time
from collections.abc import Iterable, Mapping
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2

from lossvo.atomic import write_text_atomic
from lossvo.data import kitti
from lossvo.data.synthetic import manifest, routes
from lossvo.data.synthetic.camera import calib_text, intrinsics
from lossvo.data.synthetic.parameters import (
    DEFAULT_HEIGHT,
    DEFAULT_WIDTH,
    SEQUENCES,
    check_size,
    resolve_frames,
)
from lossvo.data.synthetic.render import Renderer
from lossvo.data.synthetic.world import scene

FRAME_RATE = 10.0
"""Frames per second (KITTI's 10 Hz): the timestamps of times.txt."""
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.10: one fixed filter is 1.5x faster than choosing
    PNG_PARAMS += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH]


def times_text(n_frames: int) -> str:
    """KITTI times.txt content: one timestamp in seconds a line, FRAME_RATE Hz, starting at 0."""
    return "".join(f"{k / FRAME_RATE:e}\n" for k in range(n_frames))


def render_sequence(
    folder: Path, sequence: str, n_frames: int, height: int, width: int, seed: int,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> None:  # fmt: skip
    """Render one sequence into folder: folder/NN/{image_2/*.png, calib.txt, times.txt} and folder/NN.txt."""
    poses, world, noise = scene(sequence, n_frames, seed, spec)
    K = intrinsics(height, width)
    (folder / sequence / "image_2").mkdir(parents=True)
    (folder / sequence / "calib.txt").write_text(calib_text(K))
    (folder / sequence / "times.txt").write_text(times_text(n_frames))
    renderer = Renderer(world, K, height, width)
    for k, T in enumerate(poses):
        path = folder / sequence / "image_2" / f"{k:06d}.png"
        encoded, png = cv2.imencode(".png", renderer.render(T, noise), PNG_PARAMS)
        if not encoded:
            raise RuntimeError(f"OpenCV could not encode {path}")
        path.write_bytes(png.tobytes())  # a full disk is an OSError naming the file and the cause
    kitti.write_poses(folder / f"{sequence}.txt", poses)


def write_sequence(
    out: Path, sequence: str, n_frames: int, height: int, width: int, seed: int,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> float:  # fmt: skip
    """Render one sequence into the dataset root out, atomically; returns the seconds it took.

    Everything is rendered into a temporary folder inside out first (removed on failure); the sequence
    folder and then its poses file are moved into place only once complete.
    """
    start = time.perf_counter()
    tmp = out / f".tmp-{sequence}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        render_sequence(tmp, sequence, n_frames, height, width, seed, spec)
        (out / "sequences").mkdir(exist_ok=True)
        (out / "poses").mkdir(exist_ok=True)
        shutil.rmtree(out / "sequences" / sequence, ignore_errors=True)
        os.replace(tmp / sequence, out / "sequences" / sequence)
        os.replace(tmp / f"{sequence}.txt", kitti.pose_path(out, sequence))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return time.perf_counter() - start


PARALLEL_PIXELS = 10_000_000
"""Without an explicit worker count, a dataset of fewer pixels (frames x height x width; about 750
frames of 64x208) renders in this process: a spawned worker first spends seconds importing torch, which
is longer than rendering that many pixels takes."""


def _worker_count(jobs: int, workers: int | None, pixels: int) -> int:
    """Processes to render jobs sequences of pixels in all with: at most one a sequence and, unless
    workers says how many, one a core, or 1 below PARALLEL_PIXELS; 1 inside a daemon process (e.g. a
    pool worker), which may not have children."""
    if multiprocessing.current_process().daemon or (workers is None and pixels < PARALLEL_PIXELS):
        return 1
    return min(jobs, workers or os.cpu_count() or 1)


def _render_all(
    out: Path, counts: dict[str, int], height: int, width: int, seed: int, progress: bool,
    workers: int | None, spec: routes.RouteSpec,
) -> None:  # fmt: skip
    """Render the sequences, in parallel spawned worker processes when there are several and cores to spare
    (so a calling script needs the usual ``if __name__ == "__main__":`` guard)."""
    jobs = [(out, s, n, height, width, seed, spec) for s, n in counts.items()]
    workers = _worker_count(len(jobs), workers, sum(counts.values()) * height * width)
    pool = None
    if workers > 1:
        context = multiprocessing.get_context("spawn")  # fork is unsafe in threaded (torch) parents
        pool = ProcessPoolExecutor(workers, mp_context=context, initializer=cv2.setNumThreads, initargs=(1,))
    try:
        results = (
            pool.map(write_sequence, *zip(*jobs, strict=True)) if pool else (write_sequence(*j) for j in jobs)
        )
        for (_, s, n, *_), seconds in zip(jobs, results, strict=True):
            if progress:
                print(
                    f"synthetic: sequence {s}: {n} frames {height}x{width} in {seconds:.1f} s",
                    file=sys.stderr,
                )
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)


def generate(
    out: str | Path,
    sequences: Iterable[str] = SEQUENCES,
    frames: int | Mapping[str, int] | None = None,
    height: int = DEFAULT_HEIGHT,
    width: int = DEFAULT_WIDTH,
    seed: int = 0,
    progress: bool = True,
    workers: int | None = None,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> Path:
    """Render the synthetic dataset into out in the KITTI odometry layout; returns out as a Path.

    sequences: two-digit names; frames: None (DEFAULT_FRAMES), one count for all, or a mapping; height,
    width: pixels; seed: the same seed gives byte-identical files; spec: route families and mixes
    (:func:`lossvo.data.synthetic.routes.route_spec`). Sequences of an earlier dataset in out generated
    with the same size, seed and spec are kept. The manifest is removed first and written last, so
    an interrupted run never looks complete.
    """
    out = Path(out)
    counts = resolve_frames(sequences, frames)
    check_size(height, width)
    out.mkdir(parents=True, exist_ok=True)
    shared = manifest.header(height, width, seed, spec)
    kept = {s: n for s, n in manifest.complete_sequences(out, shared).items() if s not in counts}
    (out / manifest.MANIFEST).unlink(missing_ok=True)
    _render_all(out, counts, height, width, seed, progress, workers, spec)
    entries = {**shared, "frames": dict(sorted({**kept, **counts}.items()))}
    write_text_atomic(out / manifest.MANIFEST, json.dumps(entries, indent=2) + "\n")
    return out


def ensure_dataset(
    root: str | Path,
    sequences: Iterable[str] = SEQUENCES,
    frames: int | Mapping[str, int] | None = None,
    height: int = DEFAULT_HEIGHT,
    width: int = DEFAULT_WIDTH,
    seed: int = 0,
    progress: bool = True,
    workers: int | None = None,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> Path:
    """Root as a Path, holding the requested synthetic sequences: generated unless already there.

    Nothing is rendered when root's manifest has the same generator version, size, seed and routes and
    lists every requested sequence with the requested frame count, and those sequences' files are present.
    """
    root = Path(root)
    counts = resolve_frames(sequences, frames)
    present = manifest.complete_sequences(root, manifest.header(height, width, seed, spec))
    if all(present.get(s) == n for s, n in counts.items()):
        return root
    return generate(root, counts, counts, height, width, seed, progress, workers, spec)
