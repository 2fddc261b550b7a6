"""lossvo.data.specs: specs built from the mappings Hydra passes, one line naming the full key for bad
input, and the flat descriptions of earlier checkpoints read in the specs' form."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from omegaconf import OmegaConf

from lossvo.console import UserError, user_message
from lossvo.data import specs
from lossvo.data.datamodules import VODataModule
from lossvo.data.flow import FlowSetting
from lossvo.evaluation.checkpoints import Description
from lossvo.train import CONFIG_DIR

FIXTURES = Path(__file__).resolve().parent / "data"


def test_specs_take_defaults_and_freeze_lists() -> None:
    windows = specs.Windows.of({"seq_len": 3, "frame_steps": [1, 2, 1]})
    assert windows == specs.Windows(seq_len=3, frame_steps=(1, 2), per_epoch=None, batch_size=8)
    assert specs.Frames.of(None) == specs.Frames(**specs.DESCRIBED["frames"])
    assert specs.flow_of({"method": "dis"}) == FlowSetting("dis", 1.0)
    assert specs.Loader.of({"on_device": False}) == specs.Loader(on_device=False)


def test_splits_name_integer_sequences_with_two_digits() -> None:
    """YAML reads ``data.splits.test=[07]`` as [7]: the name is ``07``."""
    splits = specs.Splits.of({"test": [7], "train": ["00", "kitti/02"], "val": "03,04"})
    assert splits == specs.Splits(train=("00", "kitti/02"), val=("03", "04"), test=("07",))


def test_sources_keep_their_names_and_the_synthetic_root_defaults_to_the_cache(tmp_path: Path) -> None:
    sources = specs.sources_of(
        {"kitti": {"layout": "kitti", "root": "/k"}, "tum": {"layout": "tum", "root": "/t", "keep_every": 3}},
        tmp_path,
    )
    assert sources["kitti"] == specs.Source("kitti", Path("/k"))
    assert sources["tum"] == specs.Source("tum", Path("/t"), 3)
    synthetic = specs.sources_of({"s": {"layout": "synthetic", "frame_counts": {"00": 10}}}, tmp_path)["s"]
    assert synthetic.root == tmp_path / "synthetic-s" and synthetic.reader == "kitti"
    assert synthetic.render == specs.Render(frame_counts={"00": 10})
    assert specs.Source.of(synthetic.config(), "x", tmp_path) == synthetic


BAD: list[tuple[Any, Any, str]] = [
    (specs.Windows.of, {"seq_len": 1}, "data.windows.seq_len: expected an integer >= 2 frames, got 1"),
    (specs.Windows.of, {"frame_steps": [0]}, "data.windows.frame_steps: expected a list of integers >= 1"),
    (specs.Windows.of, {"frame_steps": []}, "data.windows.frame_steps: expected a list of integers >= 1"),
    (specs.Windows.of, {"per_epoch": 0}, "data.windows.per_epoch: expected null or an integer >= 1, got 0"),
    (specs.Windows.of, {"windows_per_epoch": 8}, "data.windows.windows_per_epoch: unknown key"),
    (specs.Windows.of, [3], "data.windows: expected a mapping of seq_len, frame_steps"),
    (specs.Frames.of, {"height": 8}, "data.frames.height: expected an integer >= 16 pixels, got 8"),
    (specs.Frames.of, {"crop": "maybe"}, "data.frames.crop: expected a bool, got 'maybe'"),
    (specs.Frames.of, {"height": "abc"}, "data.frames.height: expected an int, got 'abc'"),
    (specs.Windows.of, {"frame_steps": 2}, "data.windows.frame_steps: expected a list"),
    (specs.Loader.of, {"device_budget_gb": "x"}, "data.loader.device_budget_gb: expected a float, got 'x'"),
    (specs.Frames.of, {"normalization": "x"}, "data.frames.normalization: expected one of dataset, flownet"),
    (specs.Frames.of, {"statistics": {"mean": [0.5]}}, "data.frames.statistics: expected {mean: [3 floats]"),
    (specs.flow_of, {"method": "raft"}, "data.flow.method: expected one of dis, none"),
    (specs.flow_of, {"methods": "dis"}, "data.flow.methods: unknown key (expected some of method, scale"),
    (specs.Loader.of, {"on_device": "gpu"}, "data.loader.on_device: expected auto, true or false, got 'gpu'"),
    (specs.Loader.of, {"num_workers": -1}, "data.loader.num_workers: expected an integer >= 0, got -1"),
    (
        specs.Loader.of,
        {"device_budget_gb": -1},
        "data.loader.device_budget_gb: expected a number of GiB >= 0",
    ),
    (specs.Splits.of, {"test": ["00", ""]}, "data.splits.test: empty sequence name"),
    (specs.Splits.of, {"tests": ["00"]}, "data.splits.tests: unknown key (expected some of train, val"),
]


@pytest.mark.parametrize(("make", "value", "message"), BAD, ids=[m for _, _, m in BAD])
def test_bad_input_names_the_full_key(make: Any, value: Any, message: str) -> None:
    with pytest.raises(UserError) as caught:
        make(value)
    assert str(caught.value).startswith(message) and "\n" not in str(caught.value)


BAD_SOURCES: list[tuple[Any, str]] = [
    ({}, "data.sources: expected a mapping of names to datasets"),
    ({"a/b": {"layout": "kitti", "root": "/k"}}, "data.sources: expected names without '/', got 'a/b'"),
    ({"k": {"layout": "rosbag", "root": "/k"}}, "data.sources.k.layout: unknown dataset layout 'rosbag'"),
    ({"k": {"layout": "kitti"}}, "data.sources.k.root: a value is required"),
    (
        {"k": {"layout": "kitti", "root": "/k", "keep_every": 0}},
        "data.sources.k.keep_every: expected an integer",
    ),
    ({"k": {"layout": "kitti", "root": "/k", "seed": 1}}, "data.sources.k.seed: unknown key"),
    (
        {"s": {"layout": "synthetic", "frame_counts": 1}},
        "data.sources.s.frame_counts: expected an integer >= 2",
    ),
    (
        {"k": {"layout": "kitti", "root": "/k", "camera": {"K": [1]}}},
        "data.sources.k.camera.K: expected a 3x3",
    ),
]


@pytest.mark.parametrize(("value", "message"), BAD_SOURCES, ids=[m for _, m in BAD_SOURCES])
def test_bad_sources_name_the_full_key(value: Any, message: str, tmp_path: Path) -> None:
    with pytest.raises(UserError) as caught:
        specs.sources_of(value, tmp_path)
    assert str(caught.value).startswith(message)


def test_a_flat_kitti_description_reads_as_specs() -> None:
    flat = {"_target_": "lossvo.data.datamodules.KittiDataModule", "root": "/k", "train": ["00"],
            "test": ["02"], "height": 32, "width": 96, "seq_len": 3, "windows_per_epoch": 4, "flow": "dis",
            "flow_preset": "fast", "num_workers": 0, "statistics": {"mean": [0.5] * 3, "std": [0.2] * 3},
            "transforms": []}  # fmt: skip
    assert specs.nested(flat) == {
        "_target_": "lossvo.data.datamodules.VODataModule",
        "sources": {"kitti": {"layout": "kitti", "root": "/k"}},
        "splits": {"train": ["00"], "test": ["02"]},
        "frames": {"height": 32, "width": 96},
        "windows": {"seq_len": 3, "per_epoch": 4},
        "flow": {"method": "dis", "preset": "fast"},
        "loader": {"num_workers": 0},
        "statistics": {"mean": [0.5] * 3, "std": [0.2] * 3},
        "transforms": [],
    }
    assert specs.nested(specs.nested(flat)) == specs.nested(flat)


def test_flat_synthetic_and_several_dataset_descriptions_read_as_specs() -> None:
    synthetic = {"_target_": "lossvo.data.datamodules.SyntheticDataModule", "root": None, "frames": {"00": 6},
                 "render_height": 48, "seed": 1, "train": ["00"]}  # fmt: skip
    assert specs.nested(synthetic)["sources"] == {
        "synthetic": {
            "layout": "synthetic",
            "root": None,
            "frame_counts": {"00": 6},
            "render_height": 48,
            "seed": 1,
        }
    }
    datasets = {
        "kitti": {"layout": "kitti", "root": "/k", "train": ["00"]},
        "tum": {"layout": "tum", "root": "/t", "keep_every": 3, "test": ["x"]},
    }
    several = {"_target_": "lossvo.data.datamodules.MultiDataModule", "height": 32, "datasets": datasets}
    made = specs.nested(several)
    assert made["sources"] == {"kitti": {"layout": "kitti", "root": "/k"},
                               "tum": {"layout": "tum", "root": "/t", "keep_every": 3}}  # fmt: skip
    assert made["splits"] == {"train": ["kitti/00"], "val": [], "test": ["tum/x"], "unseen": []}


def test_a_description_with_withdrawn_keys_reads_without_them() -> None:
    """``windows.shares`` and ``windows.stride`` (how earlier versions drew training windows) are left out
    whatever their value, ``flow.preset`` where it is the medium one this version computes; the keys
    themselves are refused in a config."""
    recorded = {
        "sources": {"a": {"layout": "kitti"}},
        "windows": {"seq_len": 3, "stride": 2, "shares": {"a": 0.5}},
        "flow": {"method": "dis", "preset": "medium", "scale": 1.5},
    }
    assert specs.current(recorded) == {
        "sources": {"a": {"layout": "kitti"}},
        "windows": {"seq_len": 3},
        "flow": {"method": "dis", "scale": 1.5},
    }
    assert recorded["windows"]["shares"] == {"a": 0.5}  # the checkpoint's own description as it was
    for key in ("shares", "stride"):
        with pytest.raises(UserError, match=rf"^data\.windows\.{key}: unknown key"):
            specs.Windows.of({"seq_len": 3, key: 1})
    fast = {**recorded, "flow": {"method": "dis", "preset": "fast"}}
    with pytest.raises(UserError, match=r"^data\.flow\.preset='fast': this version has medium only$"):
        specs.current(fast)


@pytest.mark.parametrize("fixture", ["checkpoint_35d7877.ckpt", "checkpoint_805664b.ckpt"])
def test_an_earlier_checkpoints_description_builds_a_data_module(fixture: str, tmp_path: Path) -> None:
    data = Description.of(torch.load(FIXTURES / fixture, weights_only=True)).data
    assert data is not None and set(data["sources"]) == {"kitti"}
    arguments = {k: v for k, v in data.items() if k in ("sources", "splits", "frames", "windows", "flow")}
    module = VODataModule(**arguments)
    assert module.windows.seq_len == 3 and module.sources["kitti"].layout == "kitti"


@pytest.mark.parametrize(
    ("flat", "new"),
    [("root", "sources.NAME.root"), ("seq_len", "windows.seq_len"), ("flow_preset", None), ("stride", None),
     ("windows_per_epoch", "windows.per_epoch"), ("route_mixes", "sources.synthetic.route_mixes"),
     ("datasets", "sources"), ("test", "splits.test"), ("nope", None)],
)  # fmt: skip
def test_new_key(flat: str, new: str | None) -> None:
    assert specs.new_key(flat) == new


def test_a_flat_override_is_refused_naming_its_new_key() -> None:
    with pytest.raises(
        UserError, match=r"^data\.seq_len: not a data key; the setting is data\.windows\.seq_len"
    ):
        specs.check_overrides(["loss=euler", "data.seq_len=3"])
    with pytest.raises(UserError, match=r"^data\.root: .* data\.sources\.NAME\.root"):
        specs.check_overrides(["+data.root=/k"])
    specs.check_overrides(
        ["data.windows.seq_len=3", "data.flow=dis", "data.sources.kitti.root=/k", "seq_len=3"]
    )


def test_a_mapping_without_a_key_takes_the_described_default_a_composed_config_the_schemas() -> None:
    """A checkpoint's description without a key was trained with :data:`specs.DESCRIBED`'s value; a
    composed config takes the dataclass's default, which the shipped configs run with."""
    assert (specs.Frames.of({}).height, specs.Windows.of({}).seq_len, specs.flow_of({}).scale) == (
        184,
        7,
        1.0,
    )
    frames, flow = specs.Frames(), OmegaConf.structured(specs.Data).flow
    assert (frames.height, frames.width, flow.scale) == (160, 208, 1.5)
    windows = OmegaConf.structured(specs.Data).windows
    assert OmegaConf.to_container(windows)["seq_len"] == "${oc.select:reads.seq_len,6}"


SCHEMA_TYPES = [
    ("data.splits.train=7", None),
    ("data.frames.height=abc", "data.frames.height: expected an int, got 'abc'"),
    ("data.frames.width=1.5", "data.frames.width: expected an int, got 1.5"),
    ("data.frames.crop=maybe", "data.frames.crop: expected a bool, got 'maybe'"),
    ("data.frames.statistics=3", "data.frames.statistics: expected a mapping, got '3'"),
    ("data.windows.seq_len=true", "data.windows.seq_len: expected an int, got True"),
    ("data.windows.frame_steps=3", "data.windows.frame_steps: expected a list, got '3'"),
    ("data.windows.frame_steps=[a]", "data.windows.frame_steps: expected an int, got 'a'"),
    ("data.windows.per_epoch=all", "data.windows.per_epoch: expected an int, got 'all'"),
    ("data.windows.batch_size=abc", "data.windows.batch_size: expected an int, got 'abc'"),
    ("data.flow.scale=x", "data.flow.scale: expected a float, got 'x'"),
    ("data.loader.num_workers=two", "data.loader.num_workers: expected an int, got 'two'"),
    ("data.loader.pin_memory=maybe", "data.loader.pin_memory: expected a bool, got 'maybe'"),
    ("data.loader.device_budget_gb=x", "data.loader.device_budget_gb: expected a float, got 'x'"),
]
"""An override of each typed data key with a value of the wrong type, and its one line (None: it composes)."""


@pytest.mark.parametrize(("override", "message"), SCHEMA_TYPES, ids=[o for o, _ in SCHEMA_TYPES])
def test_the_schema_refuses_a_wrong_type_naming_the_key(override: str, message: str | None) -> None:
    with initialize_config_dir(CONFIG_DIR, version_base="1.3"):
        if message is None:
            assert compose("train", [override]).data.splits.train == 7
            return
        with pytest.raises(HydraException) as caught:
            compose("train", [override])
    assert user_message(caught.value) == message
