"""Checkpoints as the contract: evaluation from the checkpoint alone, on other data, refused overrides and
resumes, foreign files."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from helpers import eval_main, fit
from lossvo.evaluation import checkpoints
from test_train import compose_train, tiny_overrides

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sweep_job(study_sweep: Path) -> Path:
    """The shared sweep's euler job of seed 0 (read-only), named as Hydra's sweep names it."""
    (job,) = study_sweep.glob("*_loss-euler+seed-0+*")
    return job


def _env(cache: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO / "src"), "LOSSVO_CACHE": str(cache)}


def _ape(result: dict, name: str) -> float:
    return result["sequences"][name]["ape"]["trans"]["rmse"]


def test_checkpoint_records_its_data(sweep_job: Path) -> None:
    content = checkpoints.read(sweep_job / "checkpoints" / "best.ckpt")
    data = content["data"]
    assert data["_target_"] == "lossvo.data.datamodules.VODataModule"
    assert data["sources"]["kitti"]["layout"] == "kitti" and data["windows"]["seq_len"] == 3
    assert (data["frames"]["height"], data["frames"]["width"], data["frames"]["normalization"]) == (
        64,
        96,
        "dataset",
    )
    assert data["splits"]["train"] == ["00", "01"] and len(data["statistics"]["mean"]) == 3
    assert all(s > 0 for s in data["statistics"]["std"])


def test_eval_needs_only_the_checkpoint_path(sweep_job: Path, tmp_path: Path) -> None:
    ckpt = sweep_job / "checkpoints" / "best.ckpt"  # copied from the sweep folder, unquoted
    command = [sys.executable, "-m", "lossvo.eval", f"ckpt_path={ckpt}"]
    proc = subprocess.run(command, cwd=tmp_path, env=_env(tmp_path / "cache"), capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    (results,) = (tmp_path / "outputs" / "eval").glob("*/results.json")
    result, trained = json.loads(results.read_text()), json.loads((sweep_job / "results.json").read_text())
    assert list(result["sequences"]) == list(trained["sequences"]) == ["00", "02"]
    for name in result["sequences"]:
        assert _ape(result, name) == pytest.approx(_ape(trained, name), rel=1e-9)
    assert result["data"]["seq_len"] == 3 and result["data"]["train"] == ["00", "01"]


def test_eval_on_a_root_holding_only_test_sequences(
    sweep_job: Path, tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    other = tmp_path / "other"
    shutil.copytree(tiny_kitti / "sequences" / "02", other / "sequences" / "02")
    (other / "poses").mkdir()
    shutil.copy(tiny_kitti / "poses" / "02.txt", other / "poses" / "02.txt")
    out = tmp_path / "eval"
    monkeypatch.setenv("LOSSVO_CACHE", str(tmp_path / "cache"))
    status, err = eval_main(
        [
            f"ckpt_path={sweep_job / 'checkpoints' / 'best.ckpt'}",
            "data=kitti",
            f"data.sources.kitti.root={other}",
            "data.splits.test=[02]",
            "device=cpu",
            f"hydra.run.dir={out}",
        ],
        monkeypatch,
        capsys,
    )
    assert status == 0, err
    result = json.loads((out / "results.json").read_text())
    trained = json.loads((sweep_job / "results.json").read_text())
    assert (
        result["data"]["root"] == str(other.resolve()) and result["data"]["mean"] == trained["data"]["mean"]
    )
    assert _ape(result, "02") == pytest.approx(_ape(trained, "02"), rel=1e-9)  # the training normalisation


@pytest.mark.parametrize(
    ("override", "given", "recorded"),
    [("data.windows.seq_len=4", "4", "3"), ("data.frames.height=32", "32", "64")],
)
def test_contradicting_override_names_both_values(
    sweep_job: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys, override: str, given: str,
    recorded: str,
) -> None:  # fmt: skip
    key = override.split("=")[0]
    status, err = eval_main([f"ckpt_path={sweep_job / 'checkpoints' / 'best.ckpt'}", override,
                              f"hydra.run.dir={tmp_path / 'eval'}"], monkeypatch, capsys)  # fmt: skip
    assert status == 2 and len(err.strip().splitlines()) == 1
    assert f"{key}={given}" in err and f"{key}={recorded}" in err


def _resume_cfg(job: Path, tiny_kitti: Path, tmp_path: Path, *extra: str):
    overrides = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), "trainer.max_epochs=2",
                 f"ckpt_path={job / 'checkpoints' / 'last.ckpt'}", *extra]  # fmt: skip
    return compose_train(overrides, tmp_path / "run")


def test_resume_refuses_another_loss(sweep_job: Path, tiny_kitti: Path, tmp_path: Path) -> None:
    cfg = _resume_cfg(sweep_job, tiny_kitti, tmp_path, "loss=chordal")  # the same head size as euler
    with pytest.raises(checkpoints.CheckpointError, match=r"EulerLoss.*ChordalLoss"):
        fit(cfg)


def test_resume_refuses_another_network_shape(sweep_job: Path, tiny_kitti: Path, tmp_path: Path) -> None:
    cfg = _resume_cfg(sweep_job, tiny_kitti, tmp_path, "loss=euler", "model.hidden_size=24")
    with pytest.raises(
        checkpoints.CheckpointError, match=r"has shape \(6, 16\), this run's network \(6, 24\)"
    ):
        fit(cfg)


def test_resume_refuses_another_frame_size(sweep_job: Path, tiny_kitti: Path, tmp_path: Path) -> None:
    cfg = _resume_cfg(sweep_job, tiny_kitti, tmp_path, "loss=euler", "data.windows.seq_len=4")
    with pytest.raises(
        checkpoints.CheckpointError, match=r"data\.windows\.seq_len=3, this run has data\.windows\.seq_len=4"
    ):
        fit(cfg)


RECORDED = {
    "_target_": "lossvo.data.datamodules.VODataModule",
    "sources": {"synthetic": {"layout": "synthetic", "root": "/data/synthetic"}},
    "splits": {"train": ["00"], "val": ["07"], "test": ["07"]},
    "frames": {"height": 64, "width": 208, "normalization": "flownet"},
    "windows": {"seq_len": 6},
    "statistics": {"mean": [0.5] * 3, "std": [1.0] * 3},
    "dataset_root": "/data/synthetic",
}
KITTI = {
    "_target_": "lossvo.data.datamodules.VODataModule",
    "sources": {"kitti": {"layout": "kitti", "root": None}},
    "splits": {"test": ["10"]},
    "frames": {"height": 184, "width": 608, "normalization": "dataset"},
    "windows": {"seq_len": 7},
    "flow": {"method": "none"},
}


def test_evaluation_data_takes_the_network_s_settings() -> None:
    recorded = checkpoints.evaluation_data(RECORDED, None, {"splits.test": ["09"]})
    assert recorded["sources"] == RECORDED["sources"] and recorded["splits"]["test"] == ["09"]
    assert (recorded["splits"]["train"], recorded["splits"]["val"]) == ([], [])
    assert recorded["frames"]["statistics"] == RECORDED["statistics"]
    assert "dataset_root" not in recorded and "statistics" not in recorded
    chosen = checkpoints.evaluation_data(RECORDED, KITTI, {"sources.kitti.root": "/kitti"})
    assert chosen["sources"] == {"kitti": {"layout": "kitti", "root": "/kitti"}}
    assert (chosen["frames"]["height"], chosen["frames"]["width"], chosen["windows"]["seq_len"]) == (
        64,
        208,
        6,
    )
    assert (
        chosen["frames"]["normalization"] == "flownet"
    )  # a FlowNet-initialised network keeps its input range
    assert KITTI["sources"]["kitti"]["root"] is None  # the chosen config is not changed
    with pytest.raises(
        checkpoints.CheckpointError, match=r"data\.frames\.normalization='dataset'.*'flownet'"
    ):
        checkpoints.evaluation_data(RECORDED, KITTI, {"frames.normalization": "dataset"})


def test_evaluation_data_keeps_the_flow_the_network_read() -> None:
    """eval.yaml composes no network, so a chosen dataset's ``data.flow.method`` (which follows the
    network's ``reads``) reads none: the checkpoint's flow setting wins, and an override that contradicts it
    is refused."""
    flowvo = {**RECORDED, "flow": {"method": "dis", "scale": 1.5}}
    chosen = checkpoints.evaluation_data(flowvo, KITTI, {"sources.kitti.root": "/kitti"})
    assert chosen["flow"] == {"method": "dis", "scale": 1.5}
    with pytest.raises(checkpoints.CheckpointError, match=r"data\.flow\.method='none' contradicts"):
        checkpoints.evaluation_data(flowvo, KITTI, {"flow.method": "none"})
    assert "flow" not in checkpoints.evaluation_data(RECORDED, None, {})  # a network from before flow existed


def test_a_checkpoint_of_another_schema_version_is_one_line(tmp_path: Path) -> None:
    """A checkpoint records its schema_version as it is saved; one without it (written before checkpoints
    recorded it) or of another version is refused in one line naming the file, its version and the
    supported one."""
    saved: dict = {}
    checkpoints.describe(saved, None)
    assert saved["schema_version"] == checkpoints.SCHEMA_VERSION == 2
    path = tmp_path / "other.ckpt"
    content = {"hyper_parameters": {"model": {}, "loss": {}}, "state_dict": {}}
    torch.save({**content, "schema_version": 2}, path)
    assert checkpoints.read(path)["hyper_parameters"] == content["hyper_parameters"]
    again = "(supported: 2); train the network again with this version"
    for version, found in ((None, "without schema_version"), (1, "schema_version 1 is not supported")):
        torch.save(content if version is None else {**content, "schema_version": version}, path)
        with pytest.raises(checkpoints.CheckpointError) as caught:
            checkpoints.read(path)
        assert str(caught.value) == f"{path}: checkpoint {found} {again}"


def test_foreign_files_are_one_line(tmp_path: Path) -> None:
    other = tmp_path / "other.ckpt"
    torch.save({"state_dict": {}, "epoch": 3}, other)  # a Lightning-like checkpoint of something else
    with pytest.raises(checkpoints.CheckpointError, match="no lossvo network"):
        checkpoints.read(other)
    with pytest.raises(checkpoints.CheckpointError, match="checkpoint not found"):
        checkpoints.read(tmp_path / "missing.ckpt")
