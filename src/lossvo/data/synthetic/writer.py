"""Writing datasets (:func:`generate`, :func:`ensure_dataset`): their sequences, frames and image size
(defaults and checks; 160 x 512 is KITTI's 376 x 1241 scaled by about 0.42), each sequence rendered into a
temporary folder and moved into place whole, sequences in parallel processes, the manifest last."""

from __future__ import annotations

import functools
import json
import logging
import math
import multiprocessing
import os
import shutil
import tempfile
import time
from collections.abc import Iterable, Mapping
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2

from lossvo.atomic import write_text_atomic
from lossvo.console import UserError
from lossvo.data import kitti, pose_files
from lossvo.data.synthetic import layouts, manifest, routes
from lossvo.data.synthetic.camera import CameraRange, calib_text, intrinsics
from lossvo.data.synthetic.manifest import Rendering
from lossvo.data.synthetic.png import write_png
from lossvo.data.synthetic.render import Renderer
from lossvo.data.synthetic.world import scene

log = logging.getLogger(__name__)

DEFAULT_HEIGHT = 160
DEFAULT_WIDTH = 512
SEQUENCES = tuple(routes.MIXES)
DEFAULT_FRAMES = {
    "00": 240, "01": 120, "02": 240, "03": 120, "04": 100, "05": 200,
    "06": 150, "07": 120, "08": 240, "09": 150, "10": 120, "11": 150, "12": 150,
}  # fmt: skip
"""Frames per sequence when none are given; sequences not listed get FALLBACK_FRAMES."""
FALLBACK_FRAMES = 150
MIN_FRAMES = 2
MIN_SIZE = 32
MAX_SIZE = 4096


def parse_sequences(text: str, label: str = "sequences") -> tuple[str, ...]:
    """'00,07' -> ('00', '07'): comma-separated two-digit sequence numbers, duplicates dropped."""
    names = [s.strip() for s in text.split(",")]
    if not names or any(len(s) != 2 or not s.isdigit() for s in names):
        raise UserError(f"{label}: expected two-digit sequence numbers like 00,07, got {text!r}")
    return tuple(dict.fromkeys(names))


def resolve_frames(
    sequences: Iterable[str], frames: int | Mapping[str, int] | None, prefix: str = ""
) -> dict[str, int]:
    """Frames per sequence: DEFAULT_FRAMES (None), one count for all (int) or a mapping; validated
    (UserError naming the parameter after prefix, "--" on the command line)."""
    text = sequences if isinstance(sequences, str) else ",".join(sequences)
    sequences = parse_sequences(text, f"{prefix}sequences")
    if frames is None:
        counts = {s: DEFAULT_FRAMES.get(s, FALLBACK_FRAMES) for s in sequences}
    elif isinstance(frames, Mapping):
        counts = {s: int(frames[s]) for s in sequences}
    else:
        counts = dict.fromkeys(sequences, int(frames))
    for n in counts.values():
        if n < MIN_FRAMES:
            raise UserError(f"{prefix}frames: must be >= {MIN_FRAMES}, got {n}")
    return counts


def render_kitti(root: Path, sequence: str, n_frames: int, r: Rendering) -> None:
    """Render one sequence in the KITTI layout under root: sequences/NN/{image_2, calib.txt, times.txt}
    and poses/NN.txt, seen by KITTI's camera or, with ``r.cameras``, one drawn from those ranges."""
    poses, world, noise = scene(sequence, n_frames, r.seed, r.spec)
    K = r.cameras.draw(r.height, r.width, r.seed, sequence) if r.cameras else intrinsics(r.height, r.width)
    times = "".join(f"{k / 10.0:e}\n" for k in range(n_frames))  # KITTI's 10 Hz
    frames = [f"{k:06d}.png" for k in range(n_frames)]
    paths = layouts.write_files(root / "sequences" / sequence, "kitti", frames, calib_text(K), times)
    renderer = Renderer(world, K, r.height, r.width)
    for path, T in zip(paths, poses, strict=True):
        write_png(path, renderer.render(T, noise))
    kitti.pose_path(root, sequence).parent.mkdir()
    pose_files.write_poses(kitti.pose_path(root, sequence), poses)


def write_sequence(out: Path, sequence: str, n_frames: int, r: Rendering) -> float:
    """Render one sequence into the dataset root out, atomically; returns the seconds it took."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=f".tmp-{r.layout}-{sequence}-", dir=out) as name:
        tmp = Path(name)
        if r.layout == "kitti":
            render_kitti(tmp, sequence, n_frames, r)
        else:
            layouts.render_sequence(tmp, r.layout, sequence, n_frames, (r.height, r.width), r.seed, r.spec)
        for path in layouts.sequence_paths(r.layout, sequence):
            (out / path).parent.mkdir(parents=True, exist_ok=True)
            shutil.rmtree(out / path, ignore_errors=True)
            os.replace(tmp / path, out / path)
    return time.perf_counter() - start


PARALLEL_PIXELS = 10_000_000
"""Without an explicit worker count, a dataset of fewer pixels (frames x height x width) renders in this
process: a spawned worker spends seconds importing torch first."""


def _worker_count(jobs: int, workers: int | None, pixels: int) -> int:
    """Processes to render jobs sequences with: 1 below PARALLEL_PIXELS unless workers is given, and 1 in
    a daemon process (a pool worker may not have children)."""
    if multiprocessing.current_process().daemon or (workers is None and pixels < PARALLEL_PIXELS):
        return 1
    return min(jobs, workers or os.cpu_count() or 1)


def _render_all(out: Path, counts: dict[str, int], r: Rendering, progress: bool, workers: int | None) -> None:
    """Render the sequences, in spawned worker processes when there are several (so a calling script needs
    the usual ``if __name__ == "__main__":`` guard)."""
    workers = _worker_count(len(counts), workers, sum(counts.values()) * r.height * r.width)
    pool = None
    if workers > 1:
        context = multiprocessing.get_context("spawn")  # fork is unsafe in threaded (torch) parents
        pool = ProcessPoolExecutor(workers, mp_context=context, initializer=cv2.setNumThreads, initargs=(1,))
    try:
        render = functools.partial(write_sequence, out, r=r)
        results = (pool.map if pool else map)(render, counts, counts.values())
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
    """UserError naming ``key`` for cameras drawn per sequence in a layout other than KITTI's."""
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
    """(H, W) pixels a layout is rendered at: height and width where given, else the layout's default size
    times scale; checked (UserError, parameter names after prefix)."""
    layouts.check_layout(layout)
    default = (DEFAULT_HEIGHT, DEFAULT_WIDTH) if layout == "kitti" else layouts.SPECS[layout].size
    if not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
        raise UserError(f"{prefix}scale: must be a number > 0, got {scale!r}")
    scaled = round(default[0] * scale), round(default[1] * scale)
    size = (scaled[0] if height is None else height, scaled[1] if width is None else width)
    for name, value, given in (("height", size[0], height), ("width", size[1], width)):
        if not MIN_SIZE <= value <= MAX_SIZE:
            error = f"{name}: must be between {MIN_SIZE} and {MAX_SIZE} pixels, got {value}"
            if given is None:  # a size from the scale: the error names the scale
                error = (
                    f"scale: {scale:g} gives {size[0]}x{size[1]} pixels for the {layout} layout's "
                    f"{default[0]}x{default[1]} ({error})"
                )
            raise UserError(prefix + error)
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
    reuse: bool = False,
) -> Path:
    """Render the synthetic dataset into out (new, empty or a render of lossvo's) in a layout; returns out.

    frames: None (DEFAULT_FRAMES), one count for all, or a mapping; height, width: by default the layout's
    size times scale; spec: route families and mixes; cameras: ranges each sequence's camera is drawn from
    (KITTI layout only). Sequences already in out rendered with the same parameters are kept; with reuse,
    nothing is rendered when they include all the requested ones.
    """
    out, counts = Path(out), resolve_frames(sequences, frames)
    height, width = frame_size(layout, height, width, scale)
    check_cameras(layout, cameras)
    r = Rendering(height, width, seed, spec, layout, cameras)
    shared = r.header()
    present = manifest.complete_sequences(out, shared)
    if reuse and all(present.get(s) == n for s, n in counts.items()):
        return out
    manifest.check_ours(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / manifest.RENDERING).touch()
    kept = {s: n for s, n in present.items() if s not in counts}
    (out / manifest.MANIFEST).unlink(missing_ok=True)
    _render_all(out, counts, r, progress, workers)
    entries = {**shared, "frames": dict(sorted({**kept, **counts}.items()))}
    write_text_atomic(out / manifest.MANIFEST, json.dumps(entries, indent=2) + "\n")
    (out / manifest.RENDERING).unlink()
    return out


ensure_dataset = functools.partial(generate, reuse=True)
"""Root as a Path, holding the requested sequences: :func:`generate` (same parameters) with reuse, which
renders nothing when the manifest lists them all with these parameters and their files are there."""
