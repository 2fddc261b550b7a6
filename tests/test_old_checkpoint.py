"""Checkpoints written by earlier versions (tests/data/checkpoint_35d7877.ckpt, checkpoint_805664b.ckpt) load
and evaluate; the training settings this version does not have (batch transforms, ``data.windows.shares``)
are left out of their data description, since evaluation does not depend on them.

The fixture was trained by commit 35d7877, before batch transforms, on the tiny KITTI-layout dataset of
``conftest.tiny_kitti`` (data=kitti, 64x96, seq_len 3, frame steps [1, 2], ``data.mirror=0.5
data.augment=true data.zoom=1.2``, DeepVO at width_mult 1/32 with 8 LSTM units, one epoch of two
batches, seed 0); that version's own evaluation of sequence 02 gave the APE below.

The second was trained by commit 805664b (flat datamodule arguments, batch transforms) on the same dataset
(data=kitti, 64x96, seq_len 3, frame steps [1, 2], train [00, 01], val [01], test [02], a Mirror transform,
8 windows an epoch of batch 4, DeepVO at width_mult 1/32 with 8 LSTM units, one epoch, seed 0).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from helpers import eval_main
from lossvo.data import specs
from lossvo.data import transforms as T
from lossvo.evaluation import checkpoints

FIXTURE = Path(__file__).resolve().parent / "data" / "checkpoint_35d7877.ckpt"
APE_02 = 3.797535718714747
"""The APE translation RMSE (m) of sequence 02, as the version that wrote the checkpoint evaluated it."""
FIXTURE_805664B = FIXTURE.with_name("checkpoint_805664b.ckpt")
APE_02_805664B = 3.7969992695952746
"""The same for the checkpoint of 805664b."""


def test_its_augmentation_arguments_read_as_transforms() -> None:
    """``data.mirror=0.5`` as a Mirror; ``zoom`` and ``augment`` set transforms this version does not have."""
    data = checkpoints.load_network(FIXTURE).data
    assert data is not None and not {"mirror", "augment", "zoom", "reverse", "standstill"} & set(data)
    assert data["transforms"] == [T.spec(T.Mirror(0.5))]
    assert (data["frames"]["height"], data["frames"]["width"], data["windows"]["seq_len"]) == (64, 96, 3)


@pytest.mark.parametrize(("fixture", "ape"), [(FIXTURE, APE_02), (FIXTURE_805664B, APE_02_805664B)])
def test_it_evaluates_as_the_version_that_wrote_it(
    fixture: Path,
    ape: float,
    tiny_kitti: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = [
        f"ckpt_path={fixture}",
        "data=kitti",
        f"data.sources.kitti.root={tiny_kitti}",
        "data.splits.test=[02]",
        f"data.frames.cache_dir={tmp_path / 'cache'}",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    status, err = eval_main(args, monkeypatch, capsys)
    assert status == 0, err[-3000:]
    result = json.loads((tmp_path / "run" / "results.json").read_text())
    assert list(result["sequences"]) == ["02"]
    assert result["sequences"]["02"]["ape"]["trans"]["rmse"] == pytest.approx(ape, rel=1e-6)


def test_withdrawn_settings_are_left_out_and_it_evaluates_with_its_own_data(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A description in the specs' form that lists withdrawn transforms (Zoom, Jitter) and records
    ``windows.shares``: it loads without them, and evaluation from the checkpoint's own data description
    (no ``data=``) gives the APE of 805664b."""
    content = torch.load(FIXTURE_805664B, weights_only=True)
    data = specs.nested(content["data"])
    data["sources"]["kitti"]["root"] = str(tiny_kitti)
    data["frames"]["cache_dir"] = str(tmp_path / "cache")
    data["windows"]["shares"] = {"kitti": 1.0}
    zoom, jitter = ({"_target_": f"lossvo.data.transforms.{name}"} for name in ("Zoom", "Jitter"))
    data["transforms"] = [{**zoom, "factor": 1.2}, *data["transforms"], jitter]
    content["data"] = data
    ckpt = tmp_path / "withdrawn.ckpt"
    torch.save(content, ckpt)
    described = checkpoints.load_network(ckpt).data
    assert described is not None and described["transforms"] == [T.spec(T.Mirror(0.5))]
    assert "shares" not in described["windows"] and described["windows"]["seq_len"] == 3
    status, err = eval_main([f"ckpt_path={ckpt}", f"hydra.run.dir={tmp_path / 'run'}"], monkeypatch, capsys)
    assert status == 0, err[-3000:]
    result = json.loads((tmp_path / "run" / "results.json").read_text())
    assert list(result["sequences"]) == ["02"]
    assert result["sequences"]["02"]["ape"]["trans"]["rmse"] == pytest.approx(APE_02_805664B, rel=1e-6)


def test_eval_names_an_unknown_synthetic_sequence_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A network trained on the synthetic data, evaluated with ``data.splits.test=[99]``: one line, exit 2,
    and nothing rendered."""
    content = torch.load(FIXTURE, weights_only=True)
    synthetic = "lossvo.data.datamodules.SyntheticDataModule"
    frames = {"00": 10, "01": 10, "02": 10}
    content["data"] |= {
        "_target_": synthetic,
        "root": str(tmp_path / "s"),
        "frames": frames,
        "seed": 0,
        "render_height": 64,
        "render_width": 208,
        "route_families": None,
        "route_mixes": None,
    }
    ckpt = tmp_path / "synthetic.ckpt"
    torch.save(content, ckpt)
    args = [f"ckpt_path={ckpt}", "data.splits.test=[99]", f"hydra.run.dir={tmp_path / 'run'}"]
    status, err = eval_main(args, monkeypatch, capsys)
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2 and len(lines) == 1, err
    assert "data.splits.test: sequence '99' not found (available: 00, 01, 02)" in lines[0]
    assert not (tmp_path / "s").exists()
