"""Non-learned baselines, scored as the networks are (:func:`lossvo.evaluation.metrics.evaluate_relative`):
zero motion, the training split's mean motion, ORB + essential matrix with ground-truth scale, the
sequence's own mean motion (an oracle) and flow yaw + road speed (one line on DIS flow). Relative poses
are ``T_k = inv(T_w_k) @ T_w_{k+1}``; the sequences are read from the dataset a run's results.json
records, with no datamodule; :data:`ESTIMATORS` holds them by name; results and flow features are cached
per sequence by ``joblib.Memory`` (docs/report.md).
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
"""Fewest points that ``recoverPose`` must accept (in front of both cameras) for a pair to count."""
MIN_PARALLAX_PX = 0.5
"""Median displacement of the matches (pixels) below which a pair is taken as standing still."""
STRAIGHT_AHEAD = np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]])
"""Unit step along the camera's z axis (forward), no rotation."""
MAX_HAMMING = 64
"""Largest Hamming distance (of 256 bits) of an accepted ORB match."""
RATIO = 0.9
"""Lowe's ratio test: a match's distance must be below this fraction of the second-nearest one's."""
RANSAC_THRESHOLD_PX = 0.5
"""RANSAC inlier threshold for frames narrower than 640 pixels (1 pixel for larger ones, e.g. KITTI's)."""
ORB_FEATURES = 500

FLOW_SETTING = FlowSetting("dis")
"""The flow baseline's flow: the one ``data.flow.method=dis`` caches."""
FLOW_MAX_WIDTH = 320
"""Frames wider than this (pixels) are downscaled to it (area interpolation, aspect ratio kept) before the
flow: the synthetic 96x320 frames are used as stored (7-8 ms a pair on one core), KITTI's 376x1241 at
97x320."""
YAW_ROWS, YAW_COLUMNS = (0.0, 0.5), (0.0, 1.0)
"""Rows and columns (fractions of the height and width, from the top left) whose median horizontal flow is
the yaw: the upper half, mostly far away, where the translation moves pixels least and symmetrically
about the centre; the whole width."""
ROAD_ROWS, ROAD_COLUMNS = (0.75, 1.0), (1 / 3, 2 / 3)
"""The road just ahead (fractions of the height and width): the bottom quarter, the middle third."""
FLOW_CHUNK = 32
"""Frame pairs whose flow fields are held at once (the features are computed a chunk at a time)."""


@dataclass
class BaselineResult:
    """One baseline on one sequence: trajectory (N, 4, 4) float64, scores as a network's in results.json,
    the number of frame pairs for which the estimator failed and fell back (ORB only; 0 otherwise), and
    whether it came from the cache."""

    trajectory: np.ndarray
    scores: Scores
    failures: int = 0
    cached: bool = False


# --------------------------------------------------------------------------------------------------
# Estimators: (N-1, 4, 4) float64 relative poses
# --------------------------------------------------------------------------------------------------


def mean_motion(targets: Sequence[np.ndarray]) -> np.ndarray:
    """The mean relative pose of all consecutive pairs of the given sequences.

    Args:
        targets: per sequence, (N_i - 1, 4, 4) relative poses (e.g. ``Sequence.targets`` of the training
            split).
    Returns:
        (4, 4) float64 pose: mean translation (metres) and chordal L2 mean rotation (the arithmetic mean
        of the rotation matrices projected onto SO(3), roma's special Procrustes).
    """
    pairs = np.concatenate([np.asarray(t, dtype=np.float64) for t in targets])
    rotation = roma.special_procrustes(torch.from_numpy(pairs[:, :3, :3].mean(axis=0))).numpy()
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, pairs[:, :3, 3].mean(axis=0)
    return out


def repeat_motion(motion: np.ndarray, n_pairs: int) -> np.ndarray:
    """(n_pairs, 4, 4) copies of one (4, 4) relative pose."""
    return np.broadcast_to(np.asarray(motion, dtype=np.float64), (n_pairs, 4, 4)).copy()


def _orb(shape: tuple[int, ...]) -> cv2.ORB:
    """An ORB detector for frames of ``shape``. Small frames (the synthetic 96x320) get a 15-pixel border
    and patch instead of 31, which keeps most of the image usable, and 3 pyramid levels instead of 8
    (the coarser levels of a 96-pixel image hold almost no features)."""
    small = min(shape[:2]) < 300
    patch = 15 if small else 31
    return cv2.ORB.create(
        nfeatures=ORB_FEATURES, edgeThreshold=patch, patchSize=patch, nlevels=3 if small else 8
    )


@dataclass
class Features:
    """ORB features of a sequence's N frames: per frame, points (M_i, 2) float64 pixel coordinates and
    descriptors (M_i, 32) uint8; shape (H, W) of the frames."""

    points: list[np.ndarray]
    descriptors: list[np.ndarray]
    shape: tuple[int, int]


def orb_features(images: Sequence[Path]) -> Features:
    """ORB keypoints and descriptors of each image, decoded as grayscale from the original PNGs."""
    points, descriptors, orb, shape = [], [], None, (0, 0)
    for path in images:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise UserError(f"{path}: cannot decode image")
        orb, shape = orb or _orb(image.shape), image.shape[:2]
        keypoints, desc = orb.detectAndCompute(image, None)
        points.append(np.asarray(cv2.KeyPoint.convert(keypoints), dtype=np.float64).reshape(-1, 2))
        descriptors.append(np.zeros((0, 32), np.uint8) if desc is None else desc)
    return Features(points, descriptors, shape)


def signed_bits(descriptors: np.ndarray) -> torch.Tensor:
    """(M, 32) uint8 binary descriptors -> (M, 256) float32 bits mapped to ±1."""
    return torch.from_numpy(np.unpackbits(descriptors, axis=1)).float().mul_(2.0).sub_(1.0)


def mutual_matches(a: torch.Tensor, b: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Cross-checked nearest-neighbour matches in Hamming distance, as one matrix product.

    With bits mapped to ±1, the Hamming distance of 256-bit descriptors is ``(256 - a·b) / 2``. A match
    (i, j) is mutual (j is i's nearest in ``b`` and i is j's nearest in ``a``), at most
    :data:`MAX_HAMMING` bits apart, and passes Lowe's ratio test (nearest < :data:`RATIO` x second
    nearest): fewer outliers, so RANSAC needs fewer iterations.

    Args:
        a: (M1, 256), b: (M2, 256) ±1 descriptors (:func:`signed_bits`).
    Returns:
        i (P,), j (P,) int64 indices into a and b.
    """
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
    """Relative pose (frame 2 seen from frame 1) with a unit translation from matched points, or None.

    ``recoverPose`` returns ``[R | t]`` mapping frame-1 points into frame 2 (``x2 = R x1 + t``); lossvo's
    ``T_k`` is its inverse, ``[R^T | -R^T t]``.

    Args:
        p1, p2: (P, 2) float64 matched pixel coordinates in frames 1 and 2.
        K: (3, 3) intrinsics.
        threshold: RANSAC inlier threshold in pixels.
    Returns:
        (4, 4) float64 pose with ``|t| = 1`` (:data:`STRAIGHT_AHEAD` where the matches do not move), or
        None (too few matches or inliers, degenerate geometry).
    """
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
    """Monocular ORB + essential-matrix VO with ground-truth step lengths.

    ORB features matched between consecutive frames (mutual nearest neighbours in Hamming distance with a
    ratio test), ``cv2.findEssentialMat`` with ``cv2.USAC_DEFAULT`` and ``cv2.recoverPose``; each
    translation scaled to the ground-truth step length (an optimistic baseline). A pair whose matches
    move less than :data:`MIN_PARALLAX_PX` (median) gets no rotation and a step straight ahead; a pair
    with too few matches or inliers takes the previous pair's motion (``fallback`` for the first).

    Args:
        images: the sequence's N frame paths, in order.
        K: (3, 3) intrinsics of those frames; distortion: their OpenCV distortion (the keypoints are
            undistorted onto K), None or zeros for undistorted frames.
        step_lengths: (N-1,) ground-truth translation norms |t_k| in metres.
        fallback: (4, 4) motion used where the first pairs fail (e.g. :func:`mean_motion`).
    Returns:
        relative (N-1, 4, 4) float64 poses and failed (N-1,) bool, True where the pair fell back to the
        previous pair's motion.
    """
    features = orb_features(images)
    threshold = RANSAC_THRESHOLD_PX if features.shape[1] < 640 else 1.0
    points, estimates = features.points, []
    if distortion is not None and np.any(distortion):
        points = [cv2.undistortPoints(p.reshape(-1, 1, 2), K, distortion, P=K).reshape(-1, 2) for p in points]
    following = signed_bits(features.descriptors[0])
    for k in range(len(points) - 1):  # OpenCV's solvers take one pair at a time
        previous, following = following, signed_bits(features.descriptors[k + 1])
        i, j = mutual_matches(previous, following)
        estimates.append(pair_motion(points[k][i], points[k + 1][j], K, threshold))
    failed = np.array([e is None for e in estimates], dtype=bool)
    unit = np.stack([np.eye(4) if e is None else e for e in estimates]) if estimates else np.zeros((0, 4, 4))
    motion = _fill_forward(unit, failed, np.asarray(fallback, dtype=np.float64))
    lengths = torch.from_numpy(np.asarray(step_lengths, dtype=np.float64))
    motion[:, :3, 3] = geometry.scale_to_length(torch.from_numpy(motion[:, :3, 3]), lengths).numpy()
    return motion, failed


def _fill_forward(poses: np.ndarray, failed: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Each failed entry of (M, 4, 4) poses takes the last good one before it (``first`` if none)."""
    good = np.where(failed, -1, np.arange(len(poses)))
    last_good = np.maximum.accumulate(good) if len(good) else good
    table = np.concatenate((first[None], poses))
    return table[last_good + 1]


# --------------------------------------------------------------------------------------------------
# Flow yaw + road speed: one line each on DIS flow
# --------------------------------------------------------------------------------------------------


def _band(size: int, fractions: tuple[float, float]) -> slice:
    """The pixels from ``fractions[0] * size`` to ``fractions[1] * size`` (rounded)."""
    return slice(round(fractions[0] * size), round(fractions[1] * size))


def _median_per_pair(values: np.ndarray) -> np.ndarray:
    """(N, ...) -> (N,) float64 median of each pair's values."""
    flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))
    return np.median(flat.astype(np.float64), axis=1)


def flow_yaw(flow: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Each pair's yaw from its flow: ``atan(-median(u) / fx)``, the median over the rows
    :data:`YAW_ROWS` (the upper half) and columns :data:`YAW_COLUMNS`.

    A yaw (``R = Ry(yaw)``, about the camera's y axis, down; positive turns the camera to its right, as
    lossvo's Euler convention) moves the image centre by ``u = -fx tan(yaw)``: turning right, the world
    moves left. Far away, translation moves pixels little, and its sideways flow on either side of the
    centre cancels in the median. Off the centre a yaw moves pixels by ``1 + ((x - cx) / fx)^2`` times
    more, so over the whole width a pure yaw reads about 1.2x too large at the synthetic camera's 80°
    field of view.

    Args:
        flow: (N, 2, H, W) flow fields ``(u, v)`` in pixels (:func:`lossvo.data.flow.pair_flow`).
        K: (3, 3) intrinsics of the flow's frames (H x W), in pixels.
    Returns:
        (N,) float64 yaw in radians.
    """
    u = flow[:, 0, _band(flow.shape[-2], YAW_ROWS), _band(flow.shape[-1], YAW_COLUMNS)]
    return np.arctan(-_median_per_pair(u) / float(K[0, 0]))


def road_speed_feature(flow: np.ndarray) -> np.ndarray:
    """Each pair's median vertical flow of the road just ahead (rows :data:`ROAD_ROWS`, columns
    :data:`ROAD_COLUMNS`): a feature proportional to the step length.

    Driving a step d forward, a road point at image row y (camera height h above the road) moves down by
    ``v ≈ (y - cy)^2 d / (fy h)``: at fixed pixels, proportional to d (:func:`fit_speed_scale` fits the
    constant).

    Args:
        flow: (N, 2, H, W) flow fields ``(u, v)`` in pixels.
    Returns:
        (N,) float64 in pixels (positive: the road moves down the image, driving forward).
    """
    v = flow[:, 1, _band(flow.shape[-2], ROAD_ROWS), _band(flow.shape[-1], ROAD_COLUMNS)]
    return _median_per_pair(v)


def fit_speed_scale(features: np.ndarray, steps: np.ndarray) -> float:
    """The least-squares constant s (m/px) of ``|t_k| ≈ s f_k``: ``s = Σ f_k |t_k| / Σ f_k^2`` (0 where
    every feature is 0).

    Args:
        features: (M,) road-speed features in pixels (:func:`road_speed_feature`).
        steps: (M,) ground-truth step lengths ``|t_k|`` in metres.
    """
    f, t = np.asarray(features, dtype=np.float64), np.asarray(steps, dtype=np.float64)
    energy = float(f @ f)
    return float(f @ t) / energy if energy > 0 else 0.0


def flow_motion(yaw: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """The flow baseline's relative poses: ``R = Ry(yaw)`` (no pitch or roll), ``t = (0, 0, speed)``.

    Args:
        yaw: (N,) radians; speed: (N,) metres per frame pair.
    Returns:
        (N, 4, 4) float64.
    """
    yaw_t = torch.as_tensor(np.asarray(yaw, dtype=np.float64))
    angles = torch.stack((yaw_t, torch.zeros_like(yaw_t), torch.zeros_like(yaw_t)), dim=-1)
    t = torch.zeros_like(angles)
    t[:, 2] = torch.as_tensor(np.asarray(speed, dtype=np.float64))
    return geometry.make_pose(geometry.euler_to_matrix(angles), t).numpy()


@dataclass
class FlowFeatures:
    """A sequence's flow features, one per frame pair: yaw (N-1,) float64 radians (:func:`flow_yaw`) and
    road (N-1,) float64 pixels (:func:`road_speed_feature`)."""

    yaw: np.ndarray
    road: np.ndarray


def flow_size(source_hw: tuple[int, int]) -> tuple[int, int]:
    """(H, W) at which the flow of frames of ``source_hw`` is computed: as stored, or downscaled to
    :data:`FLOW_MAX_WIDTH` pixels wide (aspect ratio kept) where wider."""
    height, width = source_hw
    if width <= FLOW_MAX_WIDTH:
        return height, width
    return max(1, round(height * FLOW_MAX_WIDTH / width)), FLOW_MAX_WIDTH


def flow_features(
    images: Sequence[Path], K: np.ndarray, undistort: Undistortion | None = None
) -> FlowFeatures:
    """The flow features of a sequence's consecutive frames.

    The frames are decoded one at a time (:func:`lossvo.data.frame_cache.read_frame`, at
    :func:`flow_size`), the flow (:data:`FLOW_SETTING`) held for :data:`FLOW_CHUNK` pairs at a time: the
    memory stays small at any sequence length.

    Args:
        images: the sequence's N frame paths (PNG), in order.
        K: (3, 3) intrinsics of those frames (calib.txt's), scaled here to the flow's size.
        undistort: the frames' undistortion (:func:`lossvo.data.frame_cache.undistortion`; its K replaces
            ``K``), None for undistorted frames.
    Raises:
        KittiFormatError: an unreadable frame, or one of another size than the first.
    """
    if len(images) < 2:
        return FlowFeatures(np.zeros(0), np.zeros(0))
    check_png(images[0])
    source = png_size(images[0])
    size = flow_size(source)
    K_flow = camera.resized_intrinsics(K if undistort is None else undistort.K, source, size)
    yaw: list[np.ndarray] = []
    road: list[np.ndarray] = []
    fields: list[np.ndarray] = []
    previous, _ = read_frame(images[0], *size, undistort)
    for i, path in enumerate(images[1:], start=1):
        frame, shape = read_frame(path, *size, undistort)
        if shape != source:
            raise KittiFormatError(
                f"{path}: {shape[0]}x{shape[1]} pixels, expected {source[0]}x{source[1]} "
                "(the size of the sequence's first frame)"
            )
        fields.append(pair_flow(previous, frame, FLOW_SETTING))
        previous = frame
        if len(fields) == FLOW_CHUNK or i == len(images) - 1:
            chunk = np.stack(fields)
            yaw.append(flow_yaw(chunk, K_flow))
            road.append(road_speed_feature(chunk))
            fields = []
    return FlowFeatures(np.concatenate(yaw), np.concatenate(road))


# --------------------------------------------------------------------------------------------------
# Evaluation of one sequence
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Training:
    """What the baselines take from the training split: its mean relative pose ``mean`` (4, 4) float64
    (:func:`mean_motion`) and the road-speed constant ``speed_scale`` (m/px, :func:`fit_speed_scale`)."""

    mean: np.ndarray
    speed_scale: float


Estimator = Callable[[DatasetSequence, FlowFeatures, Training], tuple[np.ndarray, int]]
"""A baseline: (a sequence with poses (its frames, K), its flow features, the training split) ->
((N-1, 4, 4) float64 relative poses, the frame pairs where it failed and fell back)."""


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
    """Every baseline (:data:`ESTIMATORS`) on one sequence with ground truth, scored as a network's
    trajectory is (``align``, ``delta`` as the runs' results.json).

    Args:
        sequence: a sequence with poses (images, poses (N, 4, 4), K).
        training: the training split's mean motion and road-speed constant.
        features: the sequence's flow features (:func:`flow_features`, computed here if None).
    Returns:
        {baseline name: BaselineResult}, in the order of :data:`NAMES`.
    """
    gt = np.asarray(sequence.poses, dtype=np.float64)
    if features is None:
        features = flow_features(sequence.images, sequence.K, undistortion(sequence))
    out = {}
    for name, estimate in ESTIMATORS.items():
        relative, failures = estimate(sequence, features, training)
        trajectory, scores = metrics.evaluate_relative(relative, gt, align, delta)
        out[name] = BaselineResult(trajectory.numpy(), Scores.from_json(scores), failures)
    return out


# --------------------------------------------------------------------------------------------------
# The recorded data -> sequences, and the cache
# --------------------------------------------------------------------------------------------------


def training_sequences(data: DataRecord) -> list[DatasetSequence]:
    """The training split recorded in ``data``: its sequences under ``data.train_root``, read in
    ``data.train_layout`` (poses required; each of several datasets' from its source, :func:`read_sequence`).

    Raises:
        UserError: no training data or sequence recorded, or a source of several not recorded;
            KittiFormatError for a sequence that is not there.
    """
    if not data.train or data.train_root is None:
        raise UserError("the recorded training split (data.train) is empty: no training mean motion")
    where = (data.train_layout, data.train_root, data.train_keep_every, data.train_sources)
    return [read_sequence(*where, name) for name in data.train]


def read_sequence(
    layout: str, root: str, keep_every: int, sources: Mapping[str, SourceRecord], name: str
) -> DatasetSequence:
    """Sequence ``name`` of the dataset at ``root`` read in ``layout``, every ``keep_every``-th frame; of
    data of several datasets (:data:`MULTI_LAYOUT`), ``<source>/<sequence>`` read from its source.

    Raises:
        UserError: a source not in ``sources``; KittiFormatError for a sequence that is not there.
    """
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


def training_mean_motion(data: DataRecord) -> np.ndarray:
    """(4, 4) mean relative pose (:func:`mean_motion`) of the training split recorded in ``data``, read
    from the pose files under ``data.train_root`` (:func:`training_sequences`)."""
    return mean_motion([sequence.targets for sequence in training_sequences(data)])


def _files(sequence: DatasetSequence) -> dict[str, Any]:
    """What identifies a sequence's frames beyond their paths: their count, total size and latest change
    (a cached result is recomputed when the files change)."""
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
    """One sequence's flow features, from ``memory`` (joblib's cache) where it holds them."""
    return cast("FlowFeatures", memory.cache(_flow_features_of)(sequence, _files(sequence), flow_settings()))


def training_speed_scale(
    training: Sequence[DatasetSequence], memory: joblib.Memory, n_jobs: int = 1
) -> float:
    """The road-speed constant (m/px, :func:`fit_speed_scale`) of the training sequences: their road
    features (cached in ``memory``, computed ``n_jobs`` sequences at a time) against their ground-truth
    step lengths."""
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
    """The baselines of the given sequences of the recorded data, from the cache where possible.

    The sequences are read with their layout's reader (every ``keep_every``-th frame, undistorted as
    the frame cache undistorts them), the mean motion from the recorded training data. Flow features and
    results are cached by ``joblib.Memory`` in ``cache_dir``, keyed by their inputs: the sequence (its
    files, poses and camera), the training split's mean motion and road-speed constant, the alignment,
    delta and the flow and ORB settings (:data:`VERSION` among them).

    Args:
        data: a run's record of its evaluated dataset and training data (its results.json's ``data``).
        sequences: names of sequences with ground truth under ``data.root`` (e.g. those of the runs'
            results.json).
        cache_dir: the cache's folder.
        align, delta: as the runs' results.json.
        n_jobs: sequences computed in parallel (threads: OpenCV releases the GIL).
    Returns:
        {sequence: {baseline name: BaselineResult}}, in the order of ``sequences``; ``cached`` says which
        came from the cache.
    Raises:
        UserError (KittiFormatError among them): a root, a sequence or a pose file that is not there.
    """
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
    """``fn`` of each sequence, in order, ``n_jobs`` sequences at a time (threads).

    One sequence per thread, each with single-threaded torch and OpenCV: nested thread pools on a few
    cores are many times slower. torch's thread count is the calling thread's (OpenMP), so it is set in
    each call and restored after; OpenCV's is global, so it is set around the pool. The longest
    sequences start first, which balances the threads.
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
