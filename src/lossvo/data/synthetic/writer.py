"""Writing datasets: each sequence rendered into the KITTI odometry layout (or another layout,
:mod:`~lossvo.data.synthetic.layouts`) and moved into place whole, sequences in parallel processes, the
manifest last; :func:`generate` and :func:`ensure_dataset`.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import shutil
import time
from collections.abc import Iterable, Mapping
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2

from lossvo.atomic import write_text_atomic
from lossvo.console import UserError
from lossvo.data import kitti, pose_files
from lossvo.data.synthetic import layouts, manifest, routes
from lossvo.data.synthetic.camera import CameraRange, calib_text, drawn_intrinsics, intrinsics
from lossvo.data.synthetic.manifest import Rendering
from lossvo.data.synthetic.parameters import (
    DEFAULT_HEIGHT,
    DEFAULT_WIDTH,
    MAX_SIZE,
    MIN_SIZE,
    SEQUENCES,
    check_size,
    resolve_frames,
)
from lossvo.data.synthetic.png import write_png
from lossvo.data.synthetic.render import Renderer
from lossvo.data.synthetic.world import scene

log = logging.getLogger(__name__)

FRAME_RATE = 10.0
"""Frames per second (KITTI's 10 Hz): the timestamps of times.txt."""


def times_text(n_frames: int) -> str:
    """KITTI times.txt content: one timestamp in seconds a line, FRAME_RATE Hz, starting at 0."""
    return "".join(f"{k / FRAME_RATE:e}\n" for k in range(n_frames))


def render_sequence(folder: Path, sequence: str, n_frames: int, r: Rendering) -> None:
    """Render one sequence into folder: folder/NN/{image_2/*.png, calib.txt, times.txt} and folder/NN.txt,
    seen by KITTI's camera or, with ``r.cameras``, by one drawn from those ranges."""
    poses, world, noise = scene(sequence, n_frames, r.seed, r.spec)
    K = (
        intrinsics(r.height, r.width)
        if r.cameras is None
        else drawn_intrinsics(r.cameras, r.height, r.width, r.seed, sequence)
    )
    (folder / sequence / "image_2").mkdir(parents=True)
    (folder / sequence / "calib.txt").write_text(calib_text(K))
    (folder / sequence / "times.txt").write_text(times_text(n_frames))
    renderer = Renderer(world, K, r.height, r.width)
    for k, T in enumerate(poses):
        write_png(folder / sequence / "image_2" / f"{k:06d}.png", renderer.render(T, noise))
    pose_files.write_poses(folder / f"{sequence}.txt", poses)


def write_sequence(out: Path, sequence: str, n_frames: int, r: Rendering) -> float:
    """Render one sequence into the dataset root out, atomically; returns the seconds it took.

    Everything is rendered into a temporary folder inside out first (removed on failure; layouts other
    than kitti: :func:`lossvo.data.synthetic.layouts.render_sequence`); the sequence's folder (and then
    its poses file) are moved into place only once complete.
    """
    start = time.perf_counter()
    tmp = out / f".tmp-{r.layout}-{sequence}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        if r.layout == "kitti":
            render_sequence(tmp, sequence, n_frames, r)
            moves = {
                tmp / sequence: out / "sequences" / sequence,
                tmp / f"{sequence}.txt": kitti.pose_path(out, sequence),
            }
        else:
            layouts.render_sequence(
                tmp / "sequence", r.layout, sequence, n_frames, (r.height, r.width), r.seed, r.spec
            )
            moves = {tmp / "sequence": out / layouts.sequence_name(r.layout, sequence)}
        for source, target in moves.items():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.rmtree(target, ignore_errors=True)
            os.replace(source, target)
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


def _render_all(out: Path, counts: dict[str, int], r: Rendering, progress: bool, workers: int | None) -> None:
    """Render the sequences, in parallel spawned worker processes when there are several and cores to spare
    (so a calling script needs the usual ``if __name__ == "__main__":`` guard)."""
    workers = _worker_count(len(counts), workers, sum(counts.values()) * r.height * r.width)
    pool = None
    if workers > 1:
        context = multiprocessing.get_context("spawn")  # fork is unsafe in threaded (torch) parents
        pool = ProcessPoolExecutor(workers, mp_context=context, initializer=cv2.setNumThreads, initargs=(1,))
    try:
        jobs = [(out, s, n, r) for s, n in counts.items()]
        results = (
            pool.map(write_sequence, *zip(*jobs, strict=True)) if pool else (write_sequence(*j) for j in jobs)
        )
        for (s, n), seconds in zip(counts.items(), results, strict=True):
            if progress:
                log.info(
                    "synthetic: sequence %s: %d frames %dx%d in %.1f s",
                    layouts.sequence_name(r.layout, s), n, r.height, r.width, seconds,
                )  # fmt: skip
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)


def check_cameras(layout: str, cameras: CameraRange | None, key: str = "cameras") -> None:
    """UserError naming ``key`` for cameras drawn per sequence in a layout other than KITTI's, whose readers
    know one camera (TUM, TartanAir) or whose files are not written per drawn camera."""
    if cameras is not None and layout != "kitti":
        raise UserError(f"{key}: cameras drawn per sequence are rendered in the KITTI layout only (its "
                        f"calib.txt holds each sequence's K), not in {layout}")  # fmt: skip


def frame_size(
    layout: str = "kitti",
    height: int | None = None,
    width: int | None = None,
    scale: float = 1.0,
    prefix: str = "",
) -> tuple[int, int]:
    """(H, W) pixels a layout is rendered at: height and width where given, else the layout's default
    (kitti DEFAULT_HEIGHT x DEFAULT_WIDTH, the others their datasets' native sizes) times scale; checked
    (UserError, parameter names after prefix)."""
    layouts.check_layout(layout)
    default = (DEFAULT_HEIGHT, DEFAULT_WIDTH) if layout == "kitti" else layouts.SPECS[layout].size
    try:
        scaled = layouts.scaled_size(default, scale)
    except UserError as err:
        raise UserError(f"{prefix}{err}") from None
    size = (scaled[0] if height is None else height, scaled[1] if width is None else width)
    try:
        check_size(*size, prefix=prefix)
    except UserError as err:
        bad_height = not MIN_SIZE <= size[0] <= MAX_SIZE
        if (height if bad_height else width) is not None:  # a size given: the error names it
            raise
        raise UserError(  # a size from the scale: the error names the scale
            f"{prefix}scale: {scale:g} gives {size[0]}x{size[1]} pixels for the {layout} layout's "
            f"{default[0]}x{default[1]} ({str(err).removeprefix(prefix)})"
        ) from None
    return size


def generate(
    out: str | Path,
    sequences: Iterable[str] = SEQUENCES,
    frames: int | Mapping[str, int] | None = None,
    height: int | None = None,
    width: int | None = None,
    seed: int = 0,
    progress: bool = True,
    workers: int | None = None,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
    layout: str = "kitti",
    scale: float = 1.0,
    cameras: CameraRange | None = None,
) -> Path:
    """Render the synthetic dataset into out in a layout (:data:`lossvo.data.synthetic.layouts.LAYOUTS`,
    default the KITTI odometry layout); returns out as a Path.

    sequences: two-digit names (each layout names them its own way,
    :func:`lossvo.data.synthetic.layouts.sequence_name`); frames: None (DEFAULT_FRAMES), one count for
    all, or a mapping; height, width: pixels, by default the layout's size times scale
    (:func:`frame_size`); seed: the same seed gives byte-identical files; spec: route families and mixes
    (:func:`lossvo.data.synthetic.routes.route_spec`); cameras: each sequence's camera drawn from these
    ranges (KITTI layout only; None: KITTI's camera). Sequences of an earlier dataset in out generated
    with the same layout, size, seed and spec are kept. The manifest is removed first and written last,
    so an interrupted run never looks complete; out must be new, empty or a render of lossvo's
    (:func:`lossvo.data.synthetic.manifest.check_ours`: ``UserError`` otherwise).
    """
    counts = resolve_frames(sequences, frames)
    height, width = frame_size(layout, height, width, scale)
    check_cameras(layout, cameras)
    r = Rendering(height, width, seed, spec, layout, cameras)
    return _generate(Path(out), counts, r, progress, workers)


def _generate(out: Path, counts: dict[str, int], r: Rendering, progress: bool, workers: int | None) -> Path:
    """:func:`generate` of checked arguments."""
    manifest.check_ours(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / manifest.RENDERING).touch()
    shared = r.header()
    kept = {s: n for s, n in manifest.complete_sequences(out, shared).items() if s not in counts}
    (out / manifest.MANIFEST).unlink(missing_ok=True)
    _render_all(out, counts, r, progress, workers)
    entries = {**shared, "frames": dict(sorted({**kept, **counts}.items()))}
    write_text_atomic(out / manifest.MANIFEST, json.dumps(entries, indent=2) + "\n")
    (out / manifest.RENDERING).unlink()
    return out


def ensure_dataset(
    root: str | Path,
    sequences: Iterable[str] = SEQUENCES,
    frames: int | Mapping[str, int] | None = None,
    height: int | None = None,
    width: int | None = None,
    seed: int = 0,
    progress: bool = True,
    workers: int | None = None,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
    layout: str = "kitti",
    scale: float = 1.0,
    cameras: CameraRange | None = None,
) -> Path:
    """Root as a Path, holding the requested synthetic sequences: generated unless already there.

    Nothing is rendered when root's manifest has the same generator version, layout, size, seed and routes
    and lists every requested sequence with the requested frame count, and those sequences' files are
    present. Parameters as :func:`generate`.
    """
    root = Path(root)
    counts = resolve_frames(sequences, frames)
    height, width = frame_size(layout, height, width, scale)
    check_cameras(layout, cameras)
    r = Rendering(height, width, seed, spec, layout, cameras)
    present = manifest.complete_sequences(root, r.header())
    if all(present.get(s) == n for s, n in counts.items()):
        return root
    return _generate(root, counts, r, progress, workers)
