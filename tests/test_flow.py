"""Optical flow of the frame cache and the camera's intrinsics layer: the flow of a rendered yaw against the
rotation's exact flow, mirrored flow against the flow of mirrored frames, the cache computed once and
rebuilt when stale, the intrinsics channels against K after resizing."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from lossvo.console import UserError
from lossvo.data import flow, synthetic
from lossvo.data.flow import FlowSetting
from lossvo.data.transforms import Mirror
from lossvo.geometry import camera

H, W = 64, 208
"""The network's input size on the synthetic dataset (rendered at RENDER_HW, resized as the cache does)."""
RENDER_HW = (96, 320)


def _yaw(angle: float) -> np.ndarray:
    """4x4 rotation about the camera's y axis (down): positive turns the camera to its right."""
    c, s = np.cos(angle), np.sin(angle)
    T = np.eye(4)
    T[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    return T


def _frames(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3, H, W) uint8 RGB frames of ``poses`` (N, 4, 4) in sequence 00's town, rendered at RENDER_HW
    and resized to (H, W) with area interpolation; K (3, 3) at (H, W)."""
    route, world, noise = synthetic.scene("00", 40, seed=0)
    K = synthetic.intrinsics(*RENDER_HW)
    renderer = synthetic.Renderer(world, K, *RENDER_HW)
    frames = []
    for T in route[20] @ poses:
        image = cv2.resize(renderer.render(T, noise), (W, H), interpolation=cv2.INTER_AREA)
        frames.append(cv2.cvtColor(image, cv2.COLOR_BGR2RGB).transpose(2, 0, 1))
    return np.stack(frames), camera.resized_intrinsics(K, RENDER_HW, (H, W))


def _rotation_flow(K: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(2, H, W) exact flow of a pure rotation R (frame k+1's axes in frame k): x' = K R^T K^-1 x."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    points = np.stack((x, y, np.ones_like(x))).reshape(3, -1)
    moved = K @ R.T @ np.linalg.inv(K) @ points
    return (moved[:2] / moved[2] - points[:2]).reshape(2, H, W)


@pytest.mark.parametrize("angle", [0.03, -0.03])
def test_a_rendered_yaw_flows_sideways_as_the_rotation_implies(angle: float) -> None:
    """A yaw moves every pixel sideways, opposite to the turn, by more towards the image edges (the
    rotation's flow, independent of depth); DIS follows it column by column."""
    frames, K = _frames(np.stack((np.eye(4), _yaw(angle))))
    u, v = flow.pair_flow(frames[0], frames[1])
    expected = _rotation_flow(K, _yaw(angle)[:3, :3])
    assert np.sign(np.median(u)) == -np.sign(angle)  # turning right, the world moves left
    columns, exact = np.median(u, axis=0), expected[0].mean(axis=0)  # a column's pixels move alike
    error = np.abs(columns - exact) / np.abs(exact)
    assert error[16:-16].max() < 0.12 and np.median(error) < 0.05  # DIS loses pixels leaving the frame
    edge, centre = np.abs(columns[[0, -1]]).mean(), np.abs(columns[W // 2])
    assert edge > 1.3 * centre  # what the field of view implies: 1.74x at KITTI's (DIS: 1.5-1.6x)
    assert np.abs(np.median(v)) < 0.1


def test_mirrored_flow_is_the_flow_of_the_mirrored_frames() -> None:
    """The Mirror transform's flow: the fields of a driving pair, flipped with u negated, match DIS on the
    flipped frames to DIS's own precision."""
    route, _, _ = synthetic.scene("00", 40, seed=0)
    step = np.linalg.inv(route[20]) @ route[22]
    frames, _ = _frames(np.stack((np.eye(4), step @ _yaw(0.02))))
    forward = torch.from_numpy(flow.pair_flow(frames[0], frames[1]))
    flipped = torch.from_numpy(flow.pair_flow(frames[0][..., ::-1], frames[1][..., ::-1]))
    error = (flow.mirror_flow(forward) - flipped).abs()  # DIS is not mirror-symmetric to the last bit
    assert error.median() < 0.25  # px, of a mean |u| of 5.5 px
    unmirrored = (forward.flip(-1) - flipped).abs()  # flipped, u not negated: the turn the wrong way
    assert unmirrored[0].median() > 20 * error[0].median()


def _counted(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A list that grows by one for every flow field computed."""
    calls: list[int] = []
    compute = flow._Estimator.__call__
    count = lambda self, a, b: calls.append(1) or compute(self, a, b)  # noqa: E731
    monkeypatch.setattr(flow._Estimator, "__call__", count)
    return calls


def test_the_flow_is_computed_once_per_cache_and_rebuilt_when_stale(tmp_path, monkeypatch) -> None:
    frames, _ = _frames(np.stack([_yaw(0.01 * k) for k in range(4)]))
    calls = _counted(monkeypatch)
    source = {"frames": ["0", "1", "2", "3"], "bytes": 1, "mtime_ns": 1}
    setting = FlowSetting("dis")
    first = flow.ensure_flow(tmp_path, "00", frames, source, 2, setting, progress=False)
    assert first.shape == (2, 2, H, W) and first.dtype == np.float16 and len(calls) == 2
    again = flow.ensure_flow(tmp_path, "00", frames, source, 2, setting, progress=False)
    assert len(calls) == 2 and np.array_equal(again, first)  # read, not computed
    np.testing.assert_allclose(first[1], flow.pair_flow(frames[1], frames[3], setting), atol=0.02)
    calls.clear()

    flow.ensure_flow(tmp_path, "00", frames, {**source, "bytes": 2}, 2, setting, progress=False)
    assert len(calls) == 2  # the frames changed
    path = flow.flow_file(tmp_path, "00", 2, setting)
    path.write_bytes(path.read_bytes()[:-100])  # truncated
    flow.ensure_flow(tmp_path, "00", frames, {**source, "bytes": 2}, 2, setting, progress=False)
    assert len(calls) == 4
    assert json.loads(path.with_suffix(".json").read_text())["flow"] == "dis-medium"
    flow.ensure_flow(tmp_path, "00", frames, {**source, "bytes": 2}, 1, setting, progress=False)
    assert len(calls) == 7 and flow.flow_file(tmp_path, "00", 1, setting).is_file()  # another step


@pytest.mark.parametrize("method", ["dense", "farneback"])
def test_unknown_flow_methods_list_the_choices(method: str) -> None:
    with pytest.raises(UserError, match=f"^data.flow.method: expected one of dis, none, got '{method}'$"):
        FlowSetting(method)


@pytest.mark.parametrize("scale", [0.5, 5, "1.5", None])
def test_a_flow_scale_outside_one_to_four_is_refused(scale) -> None:
    with pytest.raises(
        UserError, match=rf"^data\.flow\.scale: expected a number in \[1, 4\], got {scale!r}$"
    ):
        FlowSetting("dis", scale)


def test_a_resized_flow_keeps_each_pixels_displacement_in_the_new_pixels() -> None:
    """A field computed on (h, w) frames moves a pixel as far, measured in the frames of (H, W): u scales
    by W / w and v by H / h; at the same size it is the field itself."""
    field = np.stack((np.full((96, 312), 3.0), np.full((96, 312), -1.5))).astype(np.float32)
    field[:, :, :156] *= 2  # the left half moves twice as far
    resized = flow.resized_flow(field, H, W)
    assert resized.shape == (2, H, W) and resized.dtype == np.float32
    right, left = resized[:, :, W // 2 + 2 :], resized[:, :, : W // 2 - 2]
    np.testing.assert_allclose(right[0], 3.0 * W / 312, rtol=1e-6)
    np.testing.assert_allclose(right[1], -1.5 * H / 96, rtol=1e-6)
    np.testing.assert_allclose(left[0], 6.0 * W / 312, rtol=1e-6)
    np.testing.assert_allclose(left[1], -3.0 * H / 96, rtol=1e-6)
    assert flow.resized_flow(field, 96, 312) is field


def test_a_flow_scale_computes_on_the_source_images_at_that_scale(tiny_kitti, tmp_path, monkeypatch) -> None:
    """data.flow.scale=2: every field is computed between the sequence's PNGs read at twice the cached size
    and resized to it; cached under its own key, beside the flow of scale 1, each computed once."""
    from test_datamodules import make_dm

    sizes: list[tuple[int, ...]] = []
    compute = flow._Estimator.__call__
    monkeypatch.setattr(
        flow._Estimator, "__call__", lambda self, a, b: sizes.append(a.shape) or compute(self, a, b)
    )
    fine = make_dm(tiny_kitti, tmp_path, flow="dis", flow_scale=2)
    assert set(sizes) == {(64, 192)} and len(sizes) == 27  # the tiny dataset caches 32x96 frames
    images = fine.sequences["00"].images
    first, second = (flow.frame_cache.read_frame(p, 64, 192)[0] for p in images[3:5])
    expected = flow.resized_flow(flow.pair_flow(first, second, fine.flow), 32, 96)
    cached = np.load(flow.flow_file(fine.cache_path(), "00", 1, fine.flow))
    np.testing.assert_allclose(cached[3], expected, atol=0.01)
    assert fine.description()["flow"]["scale"] == 2
    sizes.clear()
    coarse = make_dm(tiny_kitti, tmp_path, flow="dis", flow_scale=1)
    assert set(sizes) == {(32, 96)} and len(sizes) == 27
    assert not np.array_equal(np.load(flow.flow_file(coarse.cache_path(), "00", 1, coarse.flow)), cached)
    sizes.clear()
    make_dm(tiny_kitti, tmp_path, flow="dis", flow_scale=2)
    assert sizes == []


def test_the_intrinsics_channels_are_k_after_resizing() -> None:
    """The synthetic dataset's calib.txt holds K at its render size; resized to the network's input it is
    the K the renderer would use at that size, and the channels are (x - cx) / fx, (y - cy) / fy."""
    K = camera.resized_intrinsics(synthetic.intrinsics(*RENDER_HW), RENDER_HW, (H, W))
    np.testing.assert_allclose(K, synthetic.intrinsics(H, W), rtol=1e-12)
    channels = camera.intrinsics_channels(torch.from_numpy(K), H, W)
    assert channels.shape == (2, H, W)
    for x, y in ((0, 0), (W - 1, H - 1), (100, 31)):
        expected = [(x - K[0, 2]) / K[0, 0], (y - K[1, 2]) / K[1, 1]]
        torch.testing.assert_close(channels[:, y, x], torch.tensor(expected, dtype=torch.float64))
    batch = torch.from_numpy(np.stack((K, K * [[2, 1, 1], [1, 1, 1], [1, 1, 1]])))
    assert camera.intrinsics_channels(batch, H, W).shape == (2, 2, H, W)
    mirrored = camera.intrinsics_channels(camera.mirrored_intrinsics(torch.from_numpy(K), W), H, W)
    torch.testing.assert_close(mirrored, flow.mirror_flow(channels))  # x flips sign, as u does


def test_a_datamodule_caches_the_flow_of_every_pair_it_uses_once(tiny_kitti, tmp_path, monkeypatch) -> None:
    """data.flow.method: consecutive pairs of every sequence, and each frame step's pairs of the training
    ones, computed by the first datamodule and read by the next; recorded in the data's description."""
    from test_datamodules import make_dm  # the datamodule of those tests (the tiny dataset at 32x96)

    calls = _counted(monkeypatch)
    dm = make_dm(tiny_kitti, tmp_path, flow="dis", flow_scale=1, frame_steps=[1, 2])
    assert dm.flow_steps() == {"00": (1, 2), "01": (1, 2), "02": (1,)}
    assert len(calls) == 9 + 8 + 9 + 8 + 9  # 10 frames each: 9 pairs at step 1, 8 at step 2
    folder = dm.cache_path()
    assert sorted(p.name for p in folder.glob("*.flow-*.npy")) == [
        "00.flow-dis-medium-s1.npy", "00.flow-dis-medium-s2.npy", "01.flow-dis-medium-s1.npy",
        "01.flow-dis-medium-s2.npy", "02.flow-dis-medium-s1.npy",
    ]  # fmt: skip
    assert dm.description()["flow"] == {"method": "dis", "scale": 1.0}
    make_dm(tiny_kitti, tmp_path, flow="dis", flow_scale=1, frame_steps=[1, 2])
    assert len(calls) == 43  # another job of the sweep: read, not computed
    make_dm(tiny_kitti, tmp_path)  # data.flow.method=none (the default): no flow
    assert len(calls) == 43


def test_windows_carry_their_pairs_flow_and_k_and_mirror_them_together(tiny_kitti, tmp_path) -> None:
    """A step-2 training window holds fields start, start + 2, ... of the step-2 flow; mirrored in training,
    its flow is mirrored (:func:`flow.mirror_flow`) and its K's principal point too."""
    from types import SimpleNamespace

    from test_datamodules import make_dm

    dm = make_dm(
        tiny_kitti,
        tmp_path,
        flow="dis",
        frame_steps=[1, 2],
        transforms=[Mirror(1.0)],
    )
    train = dm.datasets["train"]
    i = int(np.flatnonzero(train.index[:, 3] == 2)[1])  # the second step-2 window: frames 1, 3, 5, 7
    seq, start, _, step = (int(v) for v in train.index[i])
    item = train[i]
    cached = np.load(flow.flow_file(dm.cache_path(), "00", 2, dm.flow))
    assert (seq, start, step) == (0, 1, 2) and item["flow"].dtype == torch.float16
    np.testing.assert_array_equal(item["flow"].numpy(), cached[[1, 3, 5]])
    torch.testing.assert_close(item["K"], torch.from_numpy(dm.intrinsics("00")).float())
    batch = {name: value[None] for name, value in item.items()}
    dm.trainer = SimpleNamespace(training=True)
    out = dm.on_after_batch_transfer(batch, 0)
    torch.testing.assert_close(out["flow"], flow.mirror_flow(batch["flow"].float()))
    assert out["K"][0, 0, 2] == 96 - 1 - batch["K"][0, 0, 2] and out["K"][0, 1, 2] == batch["K"][0, 1, 2]
    whole = dm.sequence_inputs("02")
    assert whole["flow"].shape == (9, 2, 32, 96) and whole["K"].shape == (3, 3)
