"""The datamodule on datasets in their own layouts: the reader chosen by ``layout``, undistortion at cache
build (K of the undistorted frames), grey frames as three channels, windows cut at gaps, ``keep_every``."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from helpers import data_module
from lossvo.console import UserError
from lossvo.data import datamodules as datamodules
from lossvo.data import frame_cache, windows
from lossvo.data.datamodules import VODataModule
from lossvo.data.sequence import Sequence
from lossvo.geometry import camera

FR1 = "rgbd_dataset_freiburg1_desk"
FRAME_HW = (48, 64)


# --------------------------------------------------------------------------------------------------
# Gaps
# --------------------------------------------------------------------------------------------------


def test_gaps_are_intervals_beyond_one_and_a_half_medians() -> None:
    times = np.array([0.0, 0.1, 0.2, 0.3, 0.5, 0.6, 0.9])
    np.testing.assert_array_equal(windows.gaps(times), [False, False, False, True, False, True])
    assert windows.gaps(np.array([1.0])).shape == (0,)


def test_training_windows_never_span_a_gap() -> None:
    gap = np.zeros(19, dtype=bool)
    gap[9] = True  # frames 9 -> 10 span a gap
    starts = windows.training_starts(20, 4, gap=gap)
    np.testing.assert_array_equal(starts, [0, 1, 2, 3, 4, 5, 6, 10, 11, 12, 13, 14, 15, 16])
    starts = windows.training_starts(20, 3, step=2, gap=gap)  # windows span 5 frames
    np.testing.assert_array_equal(starts, [0, 1, 2, 3, 4, 5, 10, 11, 12, 13, 14, 15])
    np.testing.assert_array_equal(windows.training_starts(20, 4, gap=~gap & False), np.arange(17))


# --------------------------------------------------------------------------------------------------
# Undistortion
# --------------------------------------------------------------------------------------------------


def distort(x: np.ndarray, y: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's radial-tangential model on normalised coordinates, written out (k1 k2 p1 p2 k3)."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)  # fmt: skip


def test_undistortion_samples_each_pixel_where_its_ray_lands_in_the_distorted_frame() -> None:
    K = np.array([[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]])  # EuRoC's cam0
    d = np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0])
    seq = Sequence("s", [Path("a.png")], np.zeros(1), None, K, d, (480, 752))
    undistort = frame_cache.undistortion(seq)
    assert undistort is not None and undistort.size == (480, 752)
    Kn = undistort.K
    v, u = np.mgrid[0:480:37, 0:752:53].astype(np.float64)
    xd, yd = distort((u - Kn[0, 2]) / Kn[0, 0], (v - Kn[1, 2]) / Kn[1, 1], d)
    expected_u, expected_v = K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]
    rows, cols = v.astype(int), u.astype(int)
    np.testing.assert_allclose(undistort.map_x[rows, cols], expected_u, atol=2e-3)
    np.testing.assert_allclose(undistort.map_y[rows, cols], expected_v, atol=2e-3)
    # alpha = 0: every undistorted pixel samples inside the distorted frame (no black border)
    assert undistort.map_x.min() >= -0.5 and undistort.map_x.max() <= 751.5
    assert undistort.map_y.min() >= -0.5 and undistort.map_y.max() <= 479.5
    np.testing.assert_array_equal(frame_cache.source_intrinsics(seq), Kn)


def test_no_distortion_no_undistortion() -> None:
    seq = Sequence("s", [Path("a.png")], np.zeros(1), None, np.eye(3), np.zeros(5), (4, 4))
    assert frame_cache.undistortion(seq) is None
    np.testing.assert_array_equal(frame_cache.source_intrinsics(seq), np.eye(3))


# --------------------------------------------------------------------------------------------------
# A tiny TUM layout through the datamodule
# --------------------------------------------------------------------------------------------------


def write_tum(folder: Path, frame_times: np.ndarray, gt_times: np.ndarray, grey: bool = False) -> None:
    """rgb.txt and random PNG frames (grey ones if ``grey``), groundtruth.txt moving 0.1 m/s along z."""
    rng = np.random.default_rng(0)
    (folder / "rgb").mkdir(parents=True)
    lines = []
    for t in frame_times:
        name = f"rgb/{t:.6f}.png"
        shape = FRAME_HW if grey else (*FRAME_HW, 3)
        cv2.imwrite(str(folder / name), rng.integers(0, 256, shape, dtype=np.uint8))
        lines.append(f"{t:.6f} {name}")
    (folder / "rgb.txt").write_text("# color images\n" + "\n".join(lines) + "\n")
    rows = [f"{t:.4f} 0 0 {0.1 * (t - gt_times[0]):.6f} 0 0 0 1" for t in gt_times]
    (folder / "groundtruth.txt").write_text("# ground truth\n" + "\n".join(rows) + "\n")


@pytest.fixture
def tum_root(tmp_path: Path) -> Path:
    """freiburg1 (distorted) at 30 Hz, 40 frames; the ground truth (100 Hz) has a hole from 100.45 to
    100.62 s, so the frames in it are dropped and the sequence has a gap there."""
    frames = 100.0 + np.arange(40) / 30
    gt = 99.99 + np.arange(150) / 100
    gt = gt[(gt < 100.45) | (gt > 100.62)]
    write_tum(tmp_path / "tum" / FR1, frames, gt)
    return tmp_path / "tum"


def datamodule(root: Path, cache: Path, **kwargs) -> VODataModule:
    settings = {"layout": "tum", "train": [FR1], "val": [], "test": [FR1], "height": 24, "width": 32,
                "seq_len": 4, "batch_size": 4, "num_workers": 0, "cache_dir": str(cache)}  # fmt: skip
    settings.update(kwargs)
    return data_module(root, **settings)


def test_tum_layout_through_the_datamodule(tum_root: Path, tmp_path: Path) -> None:
    dm = datamodule(tum_root, tmp_path / "cache")
    dm.prepare_data()
    dm.setup()
    seq = dm.sequences[FR1]
    assert 0 < seq.dropped < 10 and windows.gaps(seq.times).sum() == 1
    # K of the cached frames: the undistorted frames' K, resized from 48x64 to 24x32
    undistort = frame_cache.undistortion(seq)
    assert undistort is not None
    np.testing.assert_allclose(dm.intrinsics(FR1), camera.resized_intrinsics(undistort.K, FRAME_HW, (24, 32)))
    assert not np.allclose(dm.intrinsics(FR1), camera.resized_intrinsics(seq.K, FRAME_HW, (24, 32)))
    # training windows skip the gap; every pair of the sequence is still evaluated
    gap_pair = int(np.flatnonzero(windows.gaps(seq.times))[0])
    index = dm.datasets["train"].index
    assert not np.any((index[:, 1] <= gap_pair) & (index[:, 2] - 1 > gap_pair))
    assert len(index) == len(seq.images) - 3 - 3  # 3 starts lost at the gap, 3 at the end
    batch = next(iter(dm.train_dataloader()))
    assert batch["frames"].shape[1:] == (4, 3, 24, 32) and batch["K"].shape[1:] == (3, 3)
    frames = dm.sequence_frames(FR1)
    assert frames.shape == (len(seq.images), 3, 24, 32)


def set_up_with_source(
    tum_root: Path, cache: Path, **kwargs
) -> tuple[VODataModule, frame_cache.Undistortion, np.ndarray]:
    """A set-up datamodule on the tiny TUM layout, its undistortion and first source frame (BGR)."""
    dm = datamodule(tum_root, cache, **kwargs)
    dm.prepare_data()
    dm.setup()
    seq = dm.sequences[FR1]
    undistort = frame_cache.undistortion(seq)
    assert undistort is not None
    return dm, undistort, cv2.imread(str(seq.images[0]), cv2.IMREAD_COLOR)


def test_undistortion_happens_at_cache_build(tum_root: Path, tmp_path: Path) -> None:
    """The cached frame is the source frame undistorted (OpenCV's remap), then resized."""
    dm, undistort, source = set_up_with_source(tum_root, tmp_path / "cache")
    expected = cv2.resize(undistort.apply(source), (32, 24), interpolation=cv2.INTER_AREA)
    expected = cv2.cvtColor(expected, cv2.COLOR_BGR2RGB).transpose(2, 0, 1)
    np.testing.assert_array_equal(dm.sequence_frames(FR1)[0], expected)
    plain = cv2.cvtColor(cv2.resize(source, (32, 24), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
    assert not np.array_equal(dm.sequence_frames(FR1)[0], plain.transpose(2, 0, 1))


def test_grey_frames_become_three_equal_channels(tmp_path: Path) -> None:
    write_tum(tmp_path / "tum" / FR1, 100.0 + np.arange(12) / 30, 99.99 + np.arange(50) / 100, grey=True)
    dm = datamodule(tmp_path / "tum", tmp_path / "cache")
    dm.prepare_data()
    dm.setup()
    frames = np.asarray(dm.sequence_frames(FR1))
    assert frames.shape[1] == 3
    np.testing.assert_array_equal(frames[:, 0], frames[:, 1])
    np.testing.assert_array_equal(frames[:, 0], frames[:, 2])


def test_keep_every_keeps_every_nth_frame(tum_root: Path, tmp_path: Path) -> None:
    full = datamodule(tum_root, tmp_path / "cache")
    full.setup()
    third = datamodule(tum_root, tmp_path / "cache", keep_every=3)
    third.setup()
    assert third.sequences[FR1].images == full.sequences[FR1].images[::3]
    np.testing.assert_array_equal(third.sequence_poses(FR1), full.sequence_poses(FR1)[::3])
    assert third.cache_path() != full.cache_path()
    assert len(third.sequence_frames(FR1)) == len(full.sequence_frames(FR1)[::3])


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"layout": "rosbag"}, UserError, r"data\.sources\.rosbag\.layout: unknown dataset layout 'rosbag' "
                                          r"\(expected one of kitti, tum, euroc, tartanair, mimir\)"),
        ({"keep_every": 0}, UserError, r"data\.sources\.tum\.keep_every: expected an integer >= 1"),
    ],
)  # fmt: skip
def test_bad_layout_settings(tum_root: Path, tmp_path: Path, kwargs: dict, error: type, message: str) -> None:
    with pytest.raises(error, match=message):
        datamodule(tum_root, tmp_path / "cache", **kwargs)


def test_a_sequence_that_does_not_exist_names_those_found(tum_root: Path, tmp_path: Path) -> None:
    dm = datamodule(tum_root, tmp_path / "cache", test=["rgbd_dataset_freiburg1_xyz"])
    sequence = "rgbd_dataset_freiburg1_xyz"
    expected = rf"data\.splits\.test: no sequence '{sequence}' in .* it has {FR1}\)"
    with pytest.raises(UserError, match=expected):
        dm.prepare_data()


# --------------------------------------------------------------------------------------------------
# Centre crop
# --------------------------------------------------------------------------------------------------


def test_centre_crop_keeps_the_target_aspect_ratio() -> None:
    assert frame_cache.centre_crop((480, 640), (64, 208)) == (141, 0, 197, 640)  # 640 * 64 / 208 = 196.9
    assert frame_cache.centre_crop((376, 1241), (64, 208)) == (0, 9, 376, 1222)  # 376 * 208 / 64 = 1222
    assert frame_cache.centre_crop((48, 64), (24, 32)) == (0, 0, 48, 64)
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(frame_cache.cropped_intrinsics(K, (141, 0, 197, 640))[:, 2], [320, 99, 1])


def test_crop_cuts_the_centred_window_and_K_follows(tum_root: Path, tmp_path: Path) -> None:
    """48x64 frames into 16x32: the centred 32x64 window of the undistorted frame, resized; K of that window
    resized, with square pixels (fx = fy within the camera's own ratio)."""
    dm, undistort, source = set_up_with_source(tum_root, tmp_path / "cache", height=16, width=32, crop=True)
    window = undistort.apply(source)[8:40]
    expected = cv2.cvtColor(cv2.resize(window, (32, 16), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(dm.sequence_frames(FR1)[0], expected.transpose(2, 0, 1))
    K_window = undistort.K.copy()
    K_window[1, 2] -= 8
    np.testing.assert_allclose(dm.intrinsics(FR1), camera.resized_intrinsics(K_window, (32, 64), (16, 32)))
    K = dm.intrinsics(FR1)
    assert K[0, 0] / K[1, 1] == pytest.approx(
        undistort.K[0, 0] / undistort.K[1, 1]
    )  # pixels keep their shape
    whole = datamodule(tum_root, tmp_path / "cache", height=16, width=32)
    assert whole.cache_path() != dm.cache_path()


def test_a_camera_override_replaces_the_readers(tum_root: Path, tmp_path: Path) -> None:
    """data.sources.<name>.camera: another camera for every sequence (here undistorted, so nothing is
    undistorted)."""
    K = [[40.0, 0.0, 31.5], [0.0, 40.0, 23.5], [0.0, 0.0, 1.0]]
    dm = datamodule(tum_root, tmp_path / "cache", camera={"K": K})
    dm.setup()
    seq = dm.sequences[FR1]
    np.testing.assert_array_equal(seq.K, K)
    assert not seq.distortion.any() and frame_cache.undistortion(seq) is None
    np.testing.assert_allclose(dm.intrinsics(FR1), camera.resized_intrinsics(np.array(K), FRAME_HW, (24, 32)))


def test_a_camera_override_reads_a_tum_sequence_whose_name_names_no_camera(tmp_path: Path) -> None:
    """A TUM-layout recording of another camera: its name names no Freiburg set-up, so the reader alone
    refuses it, and data.sources.tum.camera gives it its camera."""
    name = "my_recording"
    write_tum(tmp_path / "tum" / name, 100.0 + np.arange(12) / 30, 99.99 + np.arange(50) / 100)
    settings = {"train": [name], "test": [name]}
    line = r"^data\.sources\.tum\.camera: sequence 'my_recording': unknown camera"
    with pytest.raises(UserError, match=line):
        datamodule(tmp_path / "tum", tmp_path / "cache", **settings).setup()
    K = [[40.0, 0.0, 31.5], [0.0, 40.0, 23.5], [0.0, 0.0, 1.0]]
    dm = datamodule(tmp_path / "tum", tmp_path / "cache", camera={"K": K}, **settings)
    dm.setup()
    np.testing.assert_array_equal(dm.sequences[name].K, K)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ({"K": [[1, 0], [0, 1]]}, r"data\.sources\.tum\.camera\.K: expected a 3x3 matrix"),
        (
            {"K": np.eye(3).tolist(), "distortion": [0.1]},
            r"data\.sources\.tum\.camera\.distortion: expected 4, 5, 8",
        ),
        ({"fx": 3}, r"data\.sources\.tum\.camera: expected \{K: "),
    ],
)
def test_bad_camera_overrides_name_the_key(tum_root: Path, tmp_path: Path, value: dict, message: str) -> None:
    with pytest.raises(UserError, match=message):
        datamodule(tum_root, tmp_path / "cache", camera=value)


def test_tiles_cut_at_gaps_and_still_cover_every_pair_once() -> None:
    gap = np.zeros(19, dtype=bool)
    gap[[6, 7, 13]] = True  # pairs 6 -> 7, 7 -> 8 and 13 -> 14 span gaps
    tiles = windows.tile(20, 4, gap)
    np.testing.assert_array_equal(
        tiles, [[0, 4], [3, 7], [6, 8], [7, 9], [8, 12], [11, 14], [13, 15], [14, 18], [17, 20]]
    )
    pairs = np.concatenate([np.arange(start, stop - 1) for start, stop in tiles])
    np.testing.assert_array_equal(pairs, np.arange(19))
    crossing = [(a, b) for a, b in tiles if gap[a : b - 1].any()]
    assert all(b - a == 2 for a, b in crossing)  # a pair across a gap is a window of its own
    np.testing.assert_array_equal(windows.tile(20, 4, np.zeros(19, dtype=bool)), windows.tile(20, 4))
