"""Non-learned baselines (:data:`ESTIMATORS`), scored as the networks are
(:func:`lossvo.evaluation.metrics.evaluate_relative`) on the data a run's results.json records; results
and flow features cached per sequence by ``joblib.Memory``. What each one is: docs/report.md.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar, cast

import cv2
import joblib
import numpy as np
import roma
import torch

from lossvo import geometry
from lossvo.console import UserError
from lossvo.data import layouts
from lossvo.data.flow import FlowSetting, pair_flow
from lossvo.data.frame_cache import Undistortion, read_frame, undistortion
from lossvo.data.kitti import KittiFormatError, check_png
from lossvo.data.sequence import Sequence as DatasetSequence
from lossvo.data.sequence import png_size
from lossvo.data.synthetic import layouts as synthetic_layouts
from lossvo.evaluation import metrics
from lossvo.evaluation.job_folder import MULTI_LAYOUT, DataRecord, Scores, SourceRecord
from lossvo.geometry import camera

log = logging.getLogger("lossvo")
T = TypeVar("T")

ZERO, MEAN, ORB = "zero motion", "mean motion (train)", "ORB+E (GT scale)"
OWN, FLOW = "own mean motion (oracle)", "flow yaw + road speed (one line)"
NAMES: tuple[str, ...] = (ZERO, MEAN, ORB, OWN, FLOW)
VERSION = 5
"""Bump when a baseline's computation changes: cached results then no longer match."""

MIN_MATCHES = 8
"""Fewest cross-checked ORB matches for which an essential matrix is attempted."""
MIN_INLIERS = 12
"""Fewest points that ``recoverPose`` must accept for a pair to count."""
MIN_PARALLAX_PX = 0.5
"""Median displacement of the matches (pixels) below which a pair is taken as standing still."""
STRAIGHT_AHEAD = np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]])
"""Unit step along the camera's z axis (forward), no rotation."""
MAX_HAMMING = 64
"""Largest Hamming distance (of 256 bits) of an accepted ORB match."""
RATIO = 0.9
"""Lowe's ratio test: a match's distance is below this fraction of the second-nearest one's."""
RANSAC_THRESHOLD_PX = 0.5
"""RANSAC inlier threshold for frames narrower than 640 pixels (1 pixel for larger ones, e.g. KITTI's)."""
ORB_FEATURES = 500

FLOW_SETTING = FlowSetting("dis")
"""The flow baseline's flow: the one ``data.flow.method=dis`` caches."""
FLOW_MAX_WIDTH = 320
"""Frames wider than this (pixels) are downscaled to it (aspect ratio kept) before the flow."""
YAW_ROWS, YAW_COLUMNS = (0.0, 0.5), (0.0, 1.0)
"""Rows and columns (fractions of the height and width) whose median horizontal flow is the yaw: the upper
half, mostly far away, where the translation moves pixels least."""
ROAD_ROWS, ROAD_COLUMNS = (0.75, 1.0), (1 / 3, 2 / 3)
"""The road just ahead (fractions of the height and width): the bottom quarter, the middle third."""


@dataclass
class BaselineResult:
    """One baseline on one sequence: trajectory (N, 4, 4) float64, its scores, the frame pairs where the
    estimator failed and fell back, and whether it came from the cache."""

    trajectory: np.ndarray
    scores: Scores
    failures: int = 0
    cached: bool = False


def mean_motion(targets: Sequence[np.ndarray]) -> np.ndarray:
    """(4, 4) float64 mean of per-sequence (N_i - 1, 4, 4) relative poses: the mean translation and the
    chordal L2 mean rotation (the mean matrix projected onto SO(3))."""
    pairs = np.concatenate([np.asarray(t, dtype=np.float64) for t in targets])
    rotation = roma.special_procrustes(torch.from_numpy(pairs[:, :3, :3].mean(axis=0))).numpy()
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, pairs[:, :3, 3].mean(axis=0)
    return out


def repeat_motion(motion: np.ndarray, n_pairs: int) -> np.ndarray:
    """(n_pairs, 4, 4) copies of one (4, 4) relative pose."""
    return np.broadcast_to(np.asarray(motion, dtype=np.float64), (n_pairs, 4, 4)).copy()


def _orb(shape: tuple[int, ...]) -> cv2.ORB:
    """An ORB detector for frames of ``shape``; small frames (96x320) get a 15-pixel border and patch and 3
    pyramid levels, keeping most of the image usable."""
    small = min(shape[:2]) < 300
    patch = 15 if small else 31
    return cv2.ORB.create(
        nfeatures=ORB_FEATURES, edgeThreshold=patch, patchSize=patch, nlevels=3 if small else 8
    )


def orb_features(images: Sequence[Path]) -> tuple[list[np.ndarray], list[np.ndarray], tuple[int, int]]:
    """Per grayscale frame, ORB points (M_i, 2) float64 pixels and descriptors (M_i, 32) uint8; (H, W)."""
    points, descriptors, orb, shape = [], [], None, (0, 0)
    for path in images:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise UserError(f"{path}: cannot decode image")
        orb, shape = orb or _orb(image.shape), image.shape[:2]
        keypoints, desc = orb.detectAndCompute(image, None)
        points.append(np.asarray(cv2.KeyPoint.convert(keypoints), dtype=np.float64).reshape(-1, 2))
        descriptors.append(np.zeros((0, 32), np.uint8) if desc is None else desc)
    return points, descriptors, shape


def signed_bits(descriptors: np.ndarray) -> torch.Tensor:
    """(M, 32) uint8 binary descriptors -> (M, 256) float32 bits mapped to ±1."""
    return torch.from_numpy(np.unpackbits(descriptors, axis=1)).float().mul_(2.0).sub_(1.0)


def mutual_matches(a: torch.Tensor, b: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest-neighbour matches i (P,), j (P,) of (M1, 256) and (M2, 256) ±1 descriptors, at most
    :data:`MAX_HAMMING` bits apart, passing the :data:`RATIO` test; Hamming distance ``(256 - a·b) / 2``."""
    if len(a) == 0 or len(b) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    similarity = a @ b.T  # (M1, M2) = 256 - 2 hamming
    top, index = similarity.topk(2, dim=1)
    nearest, second = (256.0 - top[:, 0]) / 2.0, (256.0 - top[:, 1]) / 2.0
    forward = index[:, 0]
    backward = similarity.argmax(dim=0)
    good = (backward[forward] == torch.arange(len(a))) & (nearest <= MAX_HAMMING) & (nearest < RATIO * second)
    i = torch.nonzero(good).flatten()
    return i.numpy(), forward[i].numpy()


def pair_motion(p1: np.ndarray, p2: np.ndarray, K: np.ndarray, threshold: float) -> np.ndarray | None:
    """(4, 4) relative pose with ``|t| = 1`` (frame 2 seen from frame 1) from (P, 2) matched pixels, or
    None where too few matches or inliers; ``threshold``: RANSAC's, in pixels. ``recoverPose``'s
    ``[R | t]`` maps frame 1 into frame 2: ``T_k`` is its inverse."""
    if len(p1) < MIN_MATCHES:
        return None
    if np.median(np.linalg.norm(p2 - p1, axis=1)) < MIN_PARALLAX_PX:  # no parallax: E is meaningless
        return STRAIGHT_AHEAD.copy()
    E, mask = cv2.findEssentialMat(p1, p2, K, method=cv2.USAC_DEFAULT, prob=0.999, threshold=threshold)
    if E is None or E.shape[0] < 3:
        return None
    inliers, R, t, _ = cv2.recoverPose(E[:3], p1, p2, K, mask=mask)
    if inliers < MIN_INLIERS:
        return None
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t.ravel()
    return out


def orb_essential(
    images: Sequence[Path],
    K: np.ndarray,
    step_lengths: np.ndarray,
    fallback: np.ndarray,
    distortion: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Monocular ORB + essential-matrix VO of N frames, each step scaled to its (N-1,) ground-truth length.

    A pair that fails takes the previous pair's motion (``fallback`` (4, 4) for the first). Returns
    relative (N-1, 4, 4) float64 poses and failed (N-1,) bool.
    """
    points, descriptors, shape = orb_features(images)
    threshold = RANSAC_THRESHOLD_PX if shape[1] < 640 else 1.0
    if distortion is not None and np.any(distortion):
        points = [cv2.undistortPoints(p.reshape(-1, 1, 2), K, distortion, P=K).reshape(-1, 2) for p in points]
    motion, failed = [np.asarray(fallback, dtype=np.float64)], []
    following = signed_bits(descriptors[0])
    for k in range(len(points) - 1):  # OpenCV's solvers take one pair at a time
        previous, following = following, signed_bits(descriptors[k + 1])
        i, j = mutual_matches(previous, following)
        estimate = pair_motion(points[k][i], points[k + 1][j], K, threshold)
        failed.append(estimate is None)
        motion.append(motion[-1] if estimate is None else estimate)
    relative = np.stack(motion)[1:]
    lengths = torch.from_numpy(np.asarray(step_lengths, dtype=np.float64))
    relative[:, :3, 3] = geometry.scale_to_length(torch.from_numpy(relative[:, :3, 3]), lengths).numpy()
    return relative, np.array(failed, dtype=bool)


def _band(size: int, fractions: tuple[float, float]) -> slice:
    """The pixels from ``fractions[0] * size`` to ``fractions[1] * size`` (rounded)."""
    return slice(round(fractions[0] * size), round(fractions[1] * size))


def _median_per_pair(values: np.ndarray) -> np.ndarray:
    """(N, ...) -> (N,) float64 median of each pair's values."""
    return np.median(values.reshape(len(values), -1).astype(np.float64), axis=1)


def flow_yaw(flow: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N,) yaw (rad) of (N, 2, H, W) flow fields (pixels): ``atan(-median(u) / fx)`` over
    :data:`YAW_ROWS` x :data:`YAW_COLUMNS`; a yaw moves the image centre by ``u = -fx tan(yaw)``."""
    u = flow[:, 0, _band(flow.shape[-2], YAW_ROWS), _band(flow.shape[-1], YAW_COLUMNS)]
    return np.arctan(-_median_per_pair(u) / float(K[0, 0]))


def road_speed_feature(flow: np.ndarray) -> np.ndarray:
    """(N,) median vertical flow (pixels) of the road just ahead in (N, 2, H, W) flow fields: proportional
    to the step length (``v ≈ (y - cy)^2 d / (fy h)`` at row y, camera height h)."""
    v = flow[:, 1, _band(flow.shape[-2], ROAD_ROWS), _band(flow.shape[-1], ROAD_COLUMNS)]
    return _median_per_pair(v)


def fit_speed_scale(features: np.ndarray, steps: np.ndarray) -> float:
    """The least-squares s (m/px) of ``|t_k| ≈ s f_k`` for (M,) features (px) and step lengths (m); 0 where
    every feature is 0."""
    f, t = np.asarray(features, dtype=np.float64), np.asarray(steps, dtype=np.float64)
    energy = float(f @ f)
    return float(f @ t) / energy if energy > 0 else 0.0


def flow_motion(yaw: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(N, 4, 4) float64 poses ``R = Ry(yaw)``, ``t = (0, 0, speed)`` of (N,) yaw (rad) and speed (m)."""
    yaw_t = torch.as_tensor(np.asarray(yaw, dtype=np.float64))
    angles = torch.stack((yaw_t, torch.zeros_like(yaw_t), torch.zeros_like(yaw_t)), dim=-1)
    t = torch.zeros_like(angles)
    t[:, 2] = torch.as_tensor(np.asarray(speed, dtype=np.float64))
    return geometry.make_pose(geometry.euler_to_matrix(angles), t).numpy()


@dataclass
class FlowFeatures:
    """A sequence's flow features: yaw (N-1,) rad (:func:`flow_yaw`), road (N-1,) px
    (:func:`road_speed_feature`)."""

    yaw: np.ndarray
    road: np.ndarray


def flow_size(source_hw: tuple[int, int]) -> tuple[int, int]:
    """(H, W) at which the flow of frames of ``source_hw`` is computed (:data:`FLOW_MAX_WIDTH`)."""
    height, width = source_hw
    if width <= FLOW_MAX_WIDTH:
        return height, width
    return max(1, round(height * FLOW_MAX_WIDTH / width)), FLOW_MAX_WIDTH


def flow_features(
    images: Sequence[Path], K: np.ndarray, undistort: Undistortion | None = None
) -> FlowFeatures:
    """The flow features of N frames with (3, 3) intrinsics ``K`` (``undistort``'s where given), one pair's
    flow held at a time; KittiFormatError for a frame unreadable or of another size."""
    if len(images) < 2:
        return FlowFeatures(np.zeros(0), np.zeros(0))
    check_png(images[0])
    source = png_size(images[0])
    size = flow_size(source)
    K_flow = camera.resized_intrinsics(K if undistort is None else undistort.K, source, size)
    yaw, road = np.zeros(len(images) - 1), np.zeros(len(images) - 1)
    previous, _ = read_frame(images[0], *size, undistort)
    for i, path in enumerate(images[1:]):
        frame, shape = read_frame(path, *size, undistort)
        if shape != source:
            raise KittiFormatError(
                f"{path}: {shape[0]}x{shape[1]} pixels, expected {source[0]}x{source[1]} "
                "(the size of the sequence's first frame)"
            )
        flow = pair_flow(previous, frame, FLOW_SETTING)[None]
        yaw[i], road[i] = flow_yaw(flow, K_flow)[0], road_speed_feature(flow)[0]
        previous = frame
    return FlowFeatures(yaw, road)


@dataclass(frozen=True)
class Training:
    """What the baselines take from the training split: ``mean`` (4, 4) (:func:`mean_motion`) and
    ``speed_scale`` m/px (:func:`fit_speed_scale`)."""

    mean: np.ndarray
    speed_scale: float


Estimator = Callable[[DatasetSequence, FlowFeatures, Training], tuple[np.ndarray, int]]
"""A baseline: (a sequence with poses, its flow features, the training split) -> ((N-1, 4, 4) float64
relative poses, the frame pairs where it failed and fell back)."""


def _orb_essential(
    sequence: DatasetSequence, features: FlowFeatures, training: Training
) -> tuple[np.ndarray, int]:
    steps = np.linalg.norm(sequence.targets[:, :3, 3], axis=1)
    relative, failed = orb_essential(sequence.images, sequence.K, steps, training.mean, sequence.distortion)
    return relative, int(failed.sum())


ESTIMATORS: dict[str, Estimator] = {
    ZERO: lambda sequence, _, __: (repeat_motion(np.eye(4), len(sequence.targets)), 0),
    MEAN: lambda sequence, _, training: (repeat_motion(training.mean, len(sequence.targets)), 0),
    ORB: _orb_essential,
    OWN: lambda sequence, _, __: (repeat_motion(mean_motion([sequence.targets]), len(sequence.targets)), 0),
    FLOW: lambda _, features, training: (flow_motion(features.yaw, training.speed_scale * features.road), 0),
}
"""The baselines by name, in the order of :data:`NAMES`: pure functions of a sequence."""


def sequence_baselines(
    sequence: DatasetSequence,
    training: Training,
    align: metrics.AlignMode = "none",
    delta: int = 1,
    features: FlowFeatures | None = None,
) -> dict[str, BaselineResult]:
    """Every baseline on one sequence with poses, scored as a network's trajectory is; ``features``:
    :func:`flow_features`, computed here if None."""
    gt = np.asarray(sequence.poses, dtype=np.float64)
    if features is None:
        features = flow_features(sequence.images, sequence.K, undistortion(sequence))
    out = {}
    for name, estimate in ESTIMATORS.items():
        relative, failures = estimate(sequence, features, training)
        trajectory, scores = metrics.evaluate_relative(relative, gt, align, delta)
        out[name] = BaselineResult(trajectory.numpy(), Scores.from_json(scores), failures)
    return out


def training_sequences(data: DataRecord) -> list[DatasetSequence]:
    """The training split's sequences recorded in ``data`` (:func:`read_sequence`)."""
    if not data.train or data.train_root is None:
        raise UserError("the recorded training split (data.train) is empty: no training mean motion")
    where = (data.train_layout, data.train_root, data.train_keep_every, data.train_sources)
    return [read_sequence(*where, name) for name in data.train]


def read_sequence(
    layout: str, root: str, keep_every: int, sources: Mapping[str, SourceRecord], name: str
) -> DatasetSequence:
    """Sequence ``name`` of the dataset at ``root`` read in ``layout``, every ``keep_every``-th frame; of
    data of several datasets (:data:`MULTI_LAYOUT`), ``<source>/<sequence>`` read from its source."""
    if layout == MULTI_LAYOUT:
        source_name, _, inner = name.partition("/")
        source = sources.get(source_name) if inner else None
        if source is None:
            recorded = ", ".join(sources) or "none recorded"
            raise UserError(
                f"sequence {name}: not <source>/<sequence> of a recorded dataset ({recorded}); results.json "
                "written before the sources were recorded: evaluate the checkpoint again"
            )
        layout, root, keep_every = source.layout, source.root, source.keep_every
        name = synthetic_layouts.sequence_name(layout, inner) if source.rendered else inner
    return layouts.load_sequence(layout, layouts.dataset_root(layout, root), name).every(keep_every)


def _files(sequence: DatasetSequence) -> dict[str, Any]:
    """What identifies a sequence's frames beyond their paths (a cache key): count, size, latest change."""
    stats = [p.stat() for p in sequence.images]
    return {
        "frames": len(stats),
        "bytes": sum(s.st_size for s in stats),
        "mtime_ns": max(s.st_mtime_ns for s in stats) if stats else 0,
    }


def flow_settings() -> tuple[Any, ...]:
    """Everything the flow features depend on besides the frames: the flow method, size and regions."""
    return (VERSION, FLOW_SETTING.key, FLOW_MAX_WIDTH, YAW_ROWS, YAW_COLUMNS, ROAD_ROWS, ROAD_COLUMNS)


def orb_settings() -> tuple[Any, ...]:
    """Everything ORB+E depends on besides the frames."""
    return (
        VERSION,
        ORB_FEATURES,
        MIN_MATCHES,
        MIN_INLIERS,
        MIN_PARALLAX_PX,
        MAX_HAMMING,
        RANSAC_THRESHOLD_PX,
    )


def _flow_features_of(
    sequence: DatasetSequence, files: dict[str, Any], settings: tuple[Any, ...]
) -> FlowFeatures:
    """:func:`flow_features` of a sequence (``files`` and ``settings`` key the cache only)."""
    return flow_features(sequence.images, sequence.K, undistortion(sequence))


def _baselines_of(
    sequence: DatasetSequence,
    files: dict[str, Any],
    training: Training,
    features: FlowFeatures,
    align: str,
    delta: int,
    settings: tuple[Any, ...],
) -> dict[str, BaselineResult]:
    """:func:`sequence_baselines` (``files`` and ``settings`` key the cache only)."""
    return sequence_baselines(sequence, training, cast("metrics.AlignMode", align), delta, features)


def cached_flow_features(sequence: DatasetSequence, memory: joblib.Memory) -> FlowFeatures:
    """One sequence's flow features, from joblib's cache ``memory`` where it holds them."""
    return cast("FlowFeatures", memory.cache(_flow_features_of)(sequence, _files(sequence), flow_settings()))


def training_speed_scale(
    training: Sequence[DatasetSequence], memory: joblib.Memory, n_jobs: int = 1
) -> float:
    """The road-speed constant (m/px, :func:`fit_speed_scale`) of the training sequences."""
    features = _parallel(lambda sequence: cached_flow_features(sequence, memory), training, n_jobs)
    road = np.concatenate([f.road for f in features])
    steps = np.concatenate([np.linalg.norm(s.targets[:, :3, 3], axis=1) for s in training])
    return fit_speed_scale(road, steps)


def compute_baselines(
    data: DataRecord,
    sequences: Sequence[str],
    cache_dir: Path,
    align: metrics.AlignMode = "none",
    delta: int = 1,
    n_jobs: int = 1,
) -> dict[str, dict[str, BaselineResult]]:
    """``{sequence: {baseline: result}}`` of the named sequences of a run's recorded ``data``, cached in
    ``cache_dir`` keyed by every input (the files, training split, ``align``, ``delta``, the flow and ORB
    settings); ``n_jobs`` sequences at a time (threads: OpenCV releases the GIL)."""
    memory = joblib.Memory(cache_dir, verbose=0)
    training = training_sequences(data)
    where = (data.layout, data.root, data.keep_every, data.sources)
    loaded = {n: read_sequence(*where, n) for n in sequences}
    train = Training(
        mean_motion([s.targets for s in training]), training_speed_scale(training, memory, n_jobs)
    )
    baselines_of = memory.cache(_baselines_of, ignore=["features"])
    settings = (flow_settings(), orb_settings())

    def arguments(sequence: DatasetSequence, features: FlowFeatures | None = None) -> tuple[Any, ...]:
        return (sequence, _files(sequence), train, features, align, delta, settings)

    found = {
        n: {k: replace(r, cached=True) for k, r in baselines_of(*arguments(s)).items()}
        for n, s in loaded.items()
        if baselines_of.check_call_in_cache(*arguments(s))
    }
    if todo := [n for n in sequences if n not in found]:
        log.info("baselines: computing %d sequence(s) (%s)", len(todo), ", ".join(todo))
        computed = _parallel(
            lambda s: baselines_of(*arguments(s, cached_flow_features(s, memory))),
            [loaded[n] for n in todo],
            n_jobs,
        )
        found |= dict(zip(todo, computed, strict=True))
    return {n: found[n] for n in sequences}


def _parallel(
    fn: Callable[[DatasetSequence], T], sequences: Sequence[DatasetSequence], n_jobs: int
) -> list[T]:
    """``fn`` of each sequence, in order, ``n_jobs`` sequences at a time (threads), longest first.

    Each thread runs single-threaded torch (a per-thread setting) and OpenCV (a global one): nested thread
    pools on a few cores are many times slower.
    """

    def single_threaded(sequence: DatasetSequence) -> T:
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return fn(sequence)
        finally:
            torch.set_num_threads(threads)

    order = sorted(range(len(sequences)), key=lambda i: -len(sequences[i].images))
    cv2_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        computed = joblib.Parallel(n_jobs=max(1, min(n_jobs, len(sequences))), prefer="threads")(
            joblib.delayed(single_threaded)(sequences[i]) for i in order
        )
    finally:
        cv2.setNumThreads(cv2_threads)
    by_index = dict(zip(order, computed, strict=True))
    return [by_index[i] for i in range(len(sequences))]
