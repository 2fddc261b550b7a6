"""The scale-given RPE (each predicted step scaled to the ground truth's length) beside the metric one, per
sequence and pooled, and the frame rate and metric-scale flag results.json gives each evaluated sequence."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from lossvo import geometry as g
from lossvo.data.datamodules import VODataModule
from lossvo.evaluation import metrics
from lossvo.evaluation.job_folder import JobFolderError, Results
from lossvo.evaluation.results import PooledScores, evaluate_run
from lossvo.evaluation.trajectories import integrate
from lossvo.losses import EulerLoss
from test_eval import PairStub


def ground_truth(n: int = 30, seed: int = 0) -> torch.Tensor:
    """(n, 4, 4) float64 poses: small turns, steps of 0.5 to 1.5 m."""
    gen = torch.Generator().manual_seed(seed)
    R = g.so3_exp(0.05 * torch.randn(n - 1, 3, generator=gen, dtype=torch.float64))
    t = torch.randn(n - 1, 3, generator=gen, dtype=torch.float64)
    t = t / t.norm(dim=-1, keepdim=True) * (0.5 + torch.rand(n - 1, 1, generator=gen, dtype=torch.float64))
    return integrate(g.make_pose(R, t))


def test_steps_of_the_wrong_length_score_zero_only_with_the_scale_given() -> None:
    gt = ground_truth()
    relative = g.consecutive_relative_poses(gt)
    relative[:, :3, 3] *= torch.linspace(0.3, 3.0, len(relative), dtype=torch.float64)[:, None]
    _, scores = metrics.evaluate_relative(relative, gt)
    assert scores["rpe"]["trans"]["rmse"] > 0.1
    assert scores["rpe_scaled"]["trans"]["rmse"] < 1e-9
    assert scores["rpe_scaled"]["rot_rad"]["rmse"] == pytest.approx(
        scores["rpe"]["rot_rad"]["rmse"], abs=1e-12
    )


def test_a_wrong_direction_is_an_error_with_the_scale_given() -> None:
    gt = ground_truth()
    relative = g.consecutive_relative_poses(gt)
    relative[:, :3, 3] = -relative[:, :3, 3]  # the right lengths, backwards
    _, scores = metrics.evaluate_relative(relative, gt)
    lengths = g.consecutive_relative_poses(gt)[:, :3, 3].norm(dim=-1)
    expected = float((2 * lengths).square().mean().sqrt())
    assert scores["rpe_scaled"]["trans"]["rmse"] == pytest.approx(expected, rel=1e-9)
    assert scores["rpe"]["trans"]["rmse"] == pytest.approx(expected, rel=1e-9)


def test_pooled_scale_given_rpe_is_the_rpe_of_every_scaled_step() -> None:
    pooled = PooledScores()
    sequences = [ground_truth(20, seed) for seed in (1, 2)]
    for gt in sequences:
        relative = g.consecutive_relative_poses(gt)
        relative[:, :3, 3] *= 2.0
        relative[:, 0, 3] += 0.1
        metrics.evaluate_relative(relative, gt, pooled=(pooled.ape, pooled.rpe, pooled.kitti),
                                  pooled_scaled=(pooled.rpe_scaled,))  # fmt: skip
    computed = pooled.compute()
    assert computed is not None
    each = [metrics.evaluate_relative(_doubled(gt), gt)[1]["rpe_scaled"]["trans"]["rmse"] for gt in sequences]
    mean_square = sum(e**2 * 19 for e in each) / 38
    assert computed["rpe_scaled"]["trans"]["rmse"] == pytest.approx(mean_square**0.5, rel=1e-9)
    assert computed["rpe_scaled"]["trans"]["rmse"] < computed["rpe"]["trans"]["rmse"]


def _doubled(gt: torch.Tensor) -> torch.Tensor:
    relative = g.consecutive_relative_poses(gt)
    relative[:, :3, 3] *= 2.0
    relative[:, 0, 3] += 0.1
    return relative


def test_results_json_round_trips_the_new_fields_and_reads_files_without_them(tmp_path: Path) -> None:
    from test_report import contract_example

    results = contract_example(tmp_path)
    name, entry = next(iter(results.sequences.items()))
    assert entry.scores is not None
    scores = replace(entry.scores, rpe_scaled=entry.scores.rpe)
    entry = replace(entry, scores=scores, rate_hz=10.0, rate_from="assumed", metric_scale=False)
    path = tmp_path / "results.json"
    replace(results, sequences={**results.sequences, name: entry}).write(path)
    read = Results.read(path).sequences[name]
    assert read == entry
    content = json.loads(path.read_text())
    for key in ("rpe_scaled", "rate_hz", "rate_from", "metric_scale"):
        del content["sequences"][name][key]
    path.write_text(json.dumps(content))
    old = Results.read(path).sequences[name]
    assert old.rate_hz is None and old.metric_scale is None and old.scores is not None
    assert old.scores.rpe_scaled is None


def test_a_wrong_metric_scale_value_names_its_key(tmp_path: Path) -> None:
    from test_report import contract_example

    results = contract_example(tmp_path)
    path = tmp_path / "results.json"
    results.write(path)
    content = json.loads(path.read_text())
    name = next(iter(content["sequences"]))
    content["sequences"][name]["metric_scale"] = "yes"
    path.write_text(json.dumps(content))
    with pytest.raises(JobFolderError, match=f"sequences.{name}.metric_scale"):
        Results.read(path)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("layout", "rate_from", "metric_scale"), [("tartanair", "assumed", False), ("kitti", "timestamps", True)]
)
def test_evaluation_records_each_sequences_rate_and_scale(
    tmp_path: Path, layout: str, rate_from: str, metric_scale: bool
) -> None:
    dm = VODataModule(
        sources={"drone": {"layout": "synthetic", "render_layout": layout, "frame_counts": 8,
                           "render_height": 32, "render_width": 48}},
        splits={"train": ["00"], "test": ["00"]},
        frames={"height": 16, "width": 24, "cache_dir": str(tmp_path / "cache")},
        windows={"seq_len": 2},
        loader={"num_workers": 0},
    )  # fmt: skip
    dm.prepare_data()
    stub = PairStub(g.make_pose(torch.eye(3, dtype=torch.float64).expand(256, 3, 3), torch.zeros(256, 3)))
    stub.loss, stub.data = EulerLoss(), None
    results = evaluate_run(stub, dm, tmp_path / "eval", ["00"])
    entry = results.sequences["00"]
    assert entry.rate_hz == pytest.approx(10.0) and entry.rate_from == rate_from
    assert entry.metric_scale is metric_scale
    assert entry.scores is not None and entry.scores.rpe_scaled is not None
    assert results.overall.scores is not None and results.overall.scores.rpe_scaled is not None
    written = json.loads((tmp_path / "eval" / "results.json").read_text())["sequences"]["00"]
    assert written["rate_from"] == rate_from and np.isfinite(written["rpe_scaled"]["trans"]["rmse"])
