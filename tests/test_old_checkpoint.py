"""A checkpoint written by an earlier version (tests/data/checkpoint_35d7877.ckpt: commit 35d7877, before
checkpoints recorded their ``schema_version``, with that version's flat data description) is refused in one
line naming the file and the supported version; the same weights under this version's description
(``schema_version`` 2, the specs' form) evaluate.

The fixture was trained on the tiny KITTI-layout dataset of ``conftest.tiny_kitti`` (data=kitti, 64x96,
seq_len 3, DeepVO at width_mult 1/32 with 8 LSTM units, one epoch of two batches, seed 0).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import torch

from helpers import eval_main
from lossvo.evaluation import checkpoints

FIXTURE = Path(__file__).resolve().parent / "data" / "checkpoint_35d7877.ckpt"
APE_02 = 3.797535718714747
"""The APE translation RMSE (m) of sequence 02, as the version that wrote the checkpoint evaluated it."""


def test_an_earlier_checkpoint_is_refused_in_one_line_before_any_work(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    args = [f"ckpt_path={FIXTURE}", "data=kitti", f"data.sources.kitti.root={tiny_kitti}",
            f"hydra.run.dir={tmp_path / 'run'}"]  # fmt: skip
    status, err = eval_main(args, monkeypatch, capsys)
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2 and len(lines) == 1, err
    again = "train the network again with this version"
    assert lines[0].endswith(f"{FIXTURE}: checkpoint without schema_version (supported: 2); {again}")
    assert not (tmp_path / "run" / "results.json").exists()


def current(content: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
    """The fixture's content with this version's ``schema_version`` and the data description ``data``
    (frames, windows and statistics of the fixture's)."""
    described = {"_target_": "lossvo.data.datamodules.VODataModule", "frames": {"height": 64, "width": 96},
                 "windows": {"seq_len": 3}, "transforms": []}  # fmt: skip
    described |= {"statistics": content["data"]["statistics"], **data}
    return {**content, "schema_version": checkpoints.SCHEMA_VERSION, "data": described}


def test_its_weights_under_this_versions_description_evaluate_as_before(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Evaluated from the checkpoint's own data description (no ``data=``): the APE of 35d7877."""
    sources = {"kitti": {"layout": "kitti", "root": str(tiny_kitti)}}
    data = {"sources": sources, "splits": {"train": ["00", "01"], "test": ["02"]}}
    ckpt = tmp_path / "current.ckpt"
    torch.save(current(torch.load(FIXTURE, weights_only=True), data), ckpt)
    cache, run = f"data.frames.cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run'}"
    args = [f"ckpt_path={ckpt}", cache, run]
    status, err = eval_main(args, monkeypatch, capsys)
    assert status == 0, err[-3000:]
    result = json.loads((tmp_path / "run" / "results.json").read_text())
    assert list(result["sequences"]) == ["02"]
    assert result["sequences"]["02"]["ape"]["trans"]["rmse"] == pytest.approx(APE_02, rel=1e-6)


def test_eval_names_an_unknown_synthetic_sequence_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A network trained on the synthetic data, evaluated with ``data.splits.test=[99]``: one line, exit 2,
    and nothing rendered."""
    source = {"layout": "synthetic", "root": str(tmp_path / "s"), "seed": 0, "render_height": 64,
              "render_width": 208, "frame_counts": {"00": 10, "01": 10, "02": 10}}  # fmt: skip
    data = {"sources": {"synthetic": source}, "splits": {"train": ["00", "01"], "test": ["02"]}}
    ckpt = tmp_path / "synthetic.ckpt"
    torch.save(current(torch.load(FIXTURE, weights_only=True), data), ckpt)
    args = [f"ckpt_path={ckpt}", "data.splits.test=[99]", f"hydra.run.dir={tmp_path / 'run'}"]
    status, err = eval_main(args, monkeypatch, capsys)
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2 and len(lines) == 1, err
    assert "data.splits.test: sequence '99' not found (available: 00, 01, 02)" in lines[0]
    assert not (tmp_path / "s").exists()
