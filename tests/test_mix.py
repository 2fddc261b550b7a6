"""The synthetic town seen by several platforms and cameras: cameras drawn per sequence within stated ranges,
synthetic sources rendered in other layouts, and ``data=mix``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from lossvo.console import UserError
from lossvo.data import kitti, specs
from lossvo.data.datamodules import VODataModule
from lossvo.data.synthetic import manifest
from lossvo.data.synthetic.camera import CameraRange
from lossvo.train import CONFIG_DIR

CAMERAS = {"focal": [0.5, 0.8], "principal": [0.4, 0.6], "aspect": [0.9, 1.1]}


def test_drawn_cameras_lie_in_their_ranges_and_depend_on_seed_and_sequence() -> None:
    cameras = CameraRange.of(CAMERAS, "cameras")
    Ks = np.stack([cameras.draw(100, 300, seed, s) for seed in (0, 1) for s in ("00", "01", "02")])
    fx, fy, cx, cy = Ks[:, 0, 0], Ks[:, 1, 1], Ks[:, 0, 2], Ks[:, 1, 2]
    assert np.all((fx >= 0.5 * 300) & (fx <= 0.8 * 300)) and np.all((fy / fx >= 0.9) & (fy / fx <= 1.1))
    assert np.all((cx >= 0.4 * 300) & (cx <= 0.6 * 300)) and np.all((cy >= 40) & (cy <= 60))
    assert len({round(float(f), 6) for f in fx}) == 6  # another camera for every seed and sequence
    np.testing.assert_array_equal(cameras.draw(100, 300, 0, "01"), Ks[1])


BAD_CAMERAS: list[tuple[Any, str]] = [
    ({"focal": [0.0, 0.5]}, "data.sources.car.cameras.focal: expected values > 0, got [0.0, 0.5]"),
    ({"focal": [-1, 0.5]}, "data.sources.car.cameras.focal: expected values > 0"),
    (
        {"principal": [0.5, 1.2]},
        "data.sources.car.cameras.principal: expected fractions of the frame inside (0, 1)",
    ),
    (
        {"aspect": [1.2, 0.8]},
        "data.sources.car.cameras.aspect: expected a range [low, high] with low <= high",
    ),
    ({"focal": [0.5]}, "data.sources.car.cameras.focal: expected a range [low, high] of two numbers"),
    (
        {"fov": [60, 90]},
        "data.sources.car.cameras.fov: unknown key (expected some of focal, principal, aspect)",
    ),
    ([0.5, 0.8], "data.sources.car.cameras: expected {focal: [lo, hi]"),
]


@pytest.mark.parametrize(("cameras", "message"), BAD_CAMERAS, ids=[m for _, m in BAD_CAMERAS])
def test_cameras_that_cannot_be_rendered_are_one_line_naming_the_key(
    cameras: Any, message: str, tmp_path: Path
) -> None:
    with pytest.raises(UserError) as caught:
        specs.sources_of({"car": {"layout": "synthetic", "cameras": cameras}}, tmp_path)
    assert str(caught.value).startswith(message) and "\n" not in str(caught.value)


def test_an_unknown_platform_layout_lists_the_choices_and_cameras_need_the_kitti_layout(
    tmp_path: Path,
) -> None:
    unknown = (
        r"^data\.sources\.x\.render_layout: unknown dataset layout 'rosbag' \(expected one of kitti, tum, "
    )
    with pytest.raises(UserError, match=unknown):
        specs.sources_of({"x": {"layout": "synthetic", "render_layout": "rosbag"}}, tmp_path)
    kitti_only = (
        r"^data\.sources\.x\.cameras: cameras drawn per sequence are rendered in the KITTI layout only"
    )
    with pytest.raises(UserError, match=kitti_only):
        specs.sources_of({"x": {"layout": "synthetic", "render_layout": "tum", "cameras": CAMERAS}}, tmp_path)
    with pytest.raises(UserError, match=r"^data\.sources\.x\.render_scale: expected a number > 0, got 0"):
        specs.sources_of({"x": {"layout": "synthetic", "render_scale": 0}}, tmp_path)


def test_synthetic_sources_render_into_their_own_folders(tmp_path: Path) -> None:
    made = specs.sources_of({"synthetic": {"layout": "synthetic"}, "car": {"layout": "synthetic"}}, tmp_path)
    assert (made["synthetic"].root, made["car"].root) == (tmp_path / "synthetic", tmp_path / "synthetic-car")


@pytest.mark.slow
def test_a_source_with_drawn_cameras_renders_each_sequence_with_its_own(tmp_path: Path) -> None:
    dm = VODataModule(
        sources={"car": {"layout": "synthetic", "frame_counts": 6, "render_height": 48, "render_width": 160,
                         "cameras": CAMERAS}},
        splits={"train": ["00"], "val": ["01"], "test": ["01"]},
        frames={"height": 32, "width": 96, "cache_dir": str(tmp_path)},
        windows={"seq_len": 3},
        loader={"num_workers": 0},
    )  # fmt: skip
    dm.prepare_data()
    dm.setup()
    root = tmp_path / "synthetic-car"
    Ks = [kitti.read_calib(root / "sequences" / s / "calib.txt") for s in ("00", "01")]
    assert not np.allclose(Ks[0], Ks[1])
    for K in Ks:
        assert 0.5 * 160 <= K[0, 0] <= 0.8 * 160 and 0.4 * 48 <= K[1, 2] <= 0.6 * 48
    assert manifest.read_manifest(root)["cameras"] == CAMERAS  # type: ignore[index]
    scaled = dm.intrinsics("00")
    np.testing.assert_allclose(scaled[0, 0], Ks[0][0, 0] * 96 / 160)  # resized with the frames
    batch = next(iter(dm.train_dataloader()))
    assert batch["K"].shape == (4 if len(dm.datasets["train"]) >= 4 else len(dm.datasets["train"]), 3, 3)


@pytest.mark.slow
def test_a_synthetic_source_in_another_layout_is_read_by_that_layouts_reader(tmp_path: Path) -> None:
    dm = VODataModule(
        sources={"handheld": {"layout": "synthetic", "render_layout": "tum", "render_scale": 0.1,
                              "frame_counts": 9, "keep_every": 3}},
        splits={"train": ["00"], "test": ["00"]},
        frames={"height": 32, "width": 48, "cache_dir": str(tmp_path)},
        windows={"seq_len": 2},
        loader={"num_workers": 0},
    )  # fmt: skip
    dm.prepare_data()
    dm.setup()
    assert (tmp_path / "synthetic-handheld" / "rgbd_dataset_freiburg1_synthetic_00" / "rgb.txt").is_file()
    seq = dm.sequences["00"]
    assert seq.name == "rgbd_dataset_freiburg1_synthetic_00" and len(seq.images) == 3  # 9 frames, every 3rd
    assert dm.description()["sources"]["handheld"]["render_layout"] == "tum"


def test_data_mix_composes_four_platforms() -> None:
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("train", overrides=["data=mix", "model=flowvo"])
    dm = instantiate(cfg.data, _convert_="all")
    assert {name: s.reader for name, s in dm.sources.items()} == {
        "car": "kitti", "handheld": "tum", "flying": "euroc", "drone": "tartanair"
    }  # fmt: skip
    assert dm.sources["car"].render is not None and dm.sources["car"].render.cameras is not None
    assert all(name.split("/")[1] not in ("10", "11", "12") for name in dm.splits["train"])
    assert not set(dm.splits["train"]) & set(dm.splits["test"])
    # only the car's road gives metric scale a cue: its windows train the metric translation term
    flags = {name.split("/")[0]: dm.metric_scale(name) for name in dm.splits["train"]}
    assert flags == {"car": True, "handheld": False, "flying": False, "drone": False}
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        car_only = compose("train", overrides=["data=synthetic", "model=flowvo"]).data
        experiment = compose("train", overrides=["experiment=mix"])
    # the car drives the car-only network's training and validation routes, at their lengths
    assert [f"car/{n}" for n in car_only.splits.train] == [
        n for n in dm.splits["train"] if n.startswith("car/")
    ]
    counts = car_only.sources.synthetic.frame_counts
    assert {
        n: counts[n] for n in car_only.splits.train + car_only.splits.val
    } == cfg.data.sources.car.frame_counts
    assert experiment.data == cfg.data  # experiment=mix trains on data=mix


@pytest.mark.slow
def test_a_source_no_split_reads_is_not_rendered(tmp_path: Path) -> None:
    dm = VODataModule(
        sources={"car": {"layout": "synthetic", "frame_counts": 6, "render_height": 48, "render_width": 160},
                 "drone": {"layout": "synthetic", "render_layout": "tartanair", "render_scale": 0.1}},
        splits={"train": ["car/00"], "test": ["car/00"]},
        frames={"height": 32, "width": 96, "cache_dir": str(tmp_path)},
        windows={"seq_len": 2},
        loader={"num_workers": 0},
    )  # fmt: skip
    dm.prepare_data()
    assert (tmp_path / "synthetic-car" / "sequences" / "00").is_dir()
    assert not (tmp_path / "synthetic-drone").exists()
