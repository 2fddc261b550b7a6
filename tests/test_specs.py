"""lossvo.data.specs: specs built from the mappings Hydra passes, one line naming the full key for bad
input."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from omegaconf import OmegaConf

from lossvo.console import UserError, user_message
from lossvo.data import specs
from lossvo.data.flow import FlowSetting
from lossvo.train import CONFIG_DIR


def test_specs_take_defaults_and_freeze_lists() -> None:
    windows = specs.Windows.of({"seq_len": 3, "frame_steps": [1, 2, 1]})
    assert windows == specs.Windows(seq_len=3, frame_steps=(1, 2), per_epoch=None, batch_size=8)
    assert specs.Frames.of(None) == specs.Frames()
    assert specs.flow_of({"method": "dis"}) == FlowSetting("dis", 1.5)
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


def test_a_mapping_without_a_key_takes_the_schemas_default() -> None:
    """A spec built from a mapping and a composed config take the same defaults: the dataclass's."""
    built = (specs.Frames.of({}).height, specs.Windows.of({}).seq_len, specs.flow_of({}).scale)
    frames, flow = specs.Frames(), OmegaConf.structured(specs.Data).flow
    assert built == (frames.height, 6, flow.scale) == (160, 6, 1.5)
    windows = OmegaConf.structured(specs.Data).windows
    assert OmegaConf.to_container(windows)["seq_len"] == "${oc.select:reads.seq_len,6}"
    for key in ("shares", "stride"):  # keys of earlier versions
        with pytest.raises(UserError, match=rf"^data\.windows\.{key}: unknown key"):
            specs.Windows.of({"seq_len": 3, key: 1})


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
