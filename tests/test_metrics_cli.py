"""``python -m lossvo.metrics`` reads the TUM files lossvo writes (``<seq>.tum``, ``<seq>_gt.tum``) by
their extension, with the same result as the KITTI pose files of the same trajectories."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lossvo import metrics as metrics_cli
from lossvo.data.kitti import read_poses
from lossvo.evaluation.trajectories import write_tum
from test_metrics import make_estimate, make_reference, write_kitti


def _json(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict:
    assert metrics_cli.main([*argv, "--align", "se3", "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_tum_files_give_the_kitti_files_result(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ref = make_reference(120)
    gt_txt = write_kitti(tmp_path / "00_gt.txt", ref)
    est_txt = write_kitti(tmp_path / "00.txt", make_estimate(ref))
    times = np.arange(120) * 0.1
    gt_tum, est_tum = tmp_path / "00_gt.tum", tmp_path / "00.tum"
    write_tum(gt_tum, times, read_poses(gt_txt))
    write_tum(est_tum, times, read_poses(est_txt))
    kitti = _json([str(gt_txt), str(est_txt)], capsys)
    tum = _json([str(gt_tum), str(est_tum)], capsys)
    mixed = _json([str(gt_tum), str(est_txt)], capsys)
    for result in (tum, mixed):
        assert result["ape"]["trans"]["rmse"] == pytest.approx(kitti["ape"]["trans"]["rmse"], rel=1e-5)
        assert result["rpe"]["rot_rad"]["rmse"] == pytest.approx(kitti["rpe"]["rot_rad"]["rmse"], rel=1e-4)


def test_a_malformed_tum_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "00.tum"
    bad.write_text("0.0 1 2 3\n")
    assert metrics_cli.main([str(bad), str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {bad}:1: expected 8 finite numbers") and err.count("\n") == 1
