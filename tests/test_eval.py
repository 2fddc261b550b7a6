"""Evaluation: whole-sequence inference, results.json / trajectories / plots, the CLI, the val callback."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from evo.core.metrics import APE, RPE, PoseRelation, Unit
from evo.tools import file_interface
from torch import Tensor, nn

from helpers import check_ape_against_evo, eval_main, fit
from lossvo import eval as lossvo_eval
from lossvo import geometry
from lossvo.console import UserError
from lossvo.data.kitti import read_poses
from lossvo.data.windows import tile
from lossvo.evaluation.checkpoints import load_network
from lossvo.evaluation.inference import predict_sequence
from lossvo.evaluation.results import evaluate_run
from lossvo.training.module import VOModule
from test_train import compose_train, tiny_overrides


class PairStub(nn.Module):
    """Frames carry their index (every pixel = index); the output of pair (k, k+1) is (k, k+1) and
    ``decode`` returns the true relative pose of that pair. Records the pairs it saw and its mode."""

    def __init__(self, relative: Tensor) -> None:
        super().__init__()
        self.relative = relative
        self.weight = nn.Parameter(torch.zeros(()))
        self.seen: list[Tensor] = []
        self.modes: list[bool] = []

    def forward(self, batch: dict[str, Tensor]) -> Tensor:
        self.modes.append(self.training)
        index = batch["frames"][:, :, 0, 0, 0]  # (B, L)
        out = torch.stack((index[:, :-1], index[:, 1:]), dim=-1)
        self.seen.append(out.reshape(-1, 2))
        return out

    def decode(self, pred: Tensor) -> Tensor:
        return self.relative[pred[..., 0].long()]


def _float(inputs: dict[str, Tensor]) -> dict[str, Tensor]:
    return {**inputs, "frames": inputs["frames"].float()}


def _scaled(inputs: dict[str, Tensor]) -> dict[str, Tensor]:
    return {**inputs, "frames": inputs["frames"].float() / 255}


def _random_poses(n: int, seed: int = 0) -> Tensor:
    g = torch.Generator().manual_seed(seed)
    rel = geometry.make_pose(
        geometry.so3_exp(0.1 * torch.randn(n - 1, 3, generator=g, dtype=torch.float64)),
        torch.randn(n - 1, 3, generator=g, dtype=torch.float64),
    )
    return rel


@pytest.mark.parametrize(
    ("n", "seq_len", "batch"), [(10, 3, 2), (11, 3, 16), (7, 7, 1), (8, 7, 4), (2, 5, 3)]
)
def test_predict_sequence_covers_every_pair_once(n: int, seq_len: int, batch: int) -> None:
    relative = _random_poses(n)
    stub = PairStub(relative)
    frames = np.broadcast_to(np.arange(n, dtype=np.uint8)[:, None, None, None], (n, 3, 4, 5))
    out = predict_sequence(stub, {"frames": frames}, _float, seq_len, batch_windows=batch)
    assert out.shape == (n - 1, 4, 4) and out.dtype == np.float64
    np.testing.assert_array_equal(out, relative.numpy())
    pairs = torch.cat(stub.seen)
    assert sorted(pairs[:, 0].tolist()) == list(range(n - 1))  # each pair exactly once
    assert (pairs[:, 1] == pairs[:, 0] + 1).all()
    assert all(stop - start >= 2 for start, stop in tile(n, seq_len))


def test_predict_sequence_uses_eval_mode_and_restores_it(tiny_kitti: Path, tmp_path: Path) -> None:
    stub = PairStub(_random_poses(6))
    frames = np.broadcast_to(np.arange(6, dtype=np.uint8)[:, None, None, None], (6, 3, 4, 5))
    stub.train()
    predict_sequence(stub, {"frames": frames}, _float, 3)
    assert stub.modes and not any(stub.modes) and stub.training
    stub.eval()
    predict_sequence(stub, {"frames": frames}, _float, 3)
    assert not stub.training

    module = VOModule(
        model={"_target_": "lossvo.models.DeepVO", "out_dim": 6, "height": 64, "width": 64,
               "width_mult": 0.0625, "hidden_size": 8, "head_dropout": 0.9, "conv_dropout": 0.5},
        loss={"_target_": "lossvo.losses.ChordalLoss"},
        optimizer={"_target_": "torch.optim.Adam", "_partial_": True},
    )  # fmt: skip
    module.train()
    images = np.random.default_rng(0).integers(0, 256, (9, 3, 64, 64), dtype=np.uint8)
    a = predict_sequence(module, {"frames": images}, _scaled, 4)
    b = predict_sequence(module, {"frames": images}, _scaled, 4)
    np.testing.assert_array_equal(a, b)  # dropout off
    assert module.training
    # equal to per-window forward calls, LSTM reset per window
    module.eval()
    with torch.no_grad():
        x = torch.from_numpy(images).float() / 255
        windows = [module.decode(module({"frames": x[s:e][None]}))[0] for s, e in tile(9, 4)]
    np.testing.assert_allclose(a, torch.cat(windows).double().numpy(), atol=1e-5)
    carried = predict_sequence(module, {"frames": images}, _scaled, 4, carry_state=True)
    assert carried.shape == (8, 4, 4)


@pytest.fixture(scope="module")
def trained_run(tiny_kitti: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One epoch of training on the tiny dataset; the run folder."""
    tmp = tmp_path_factory.mktemp("eval_run")
    overrides = [*tiny_overrides(tiny_kitti, tmp / "cache"), "loss=quat", "trainer.max_epochs=1"]
    cfg = compose_train(overrides, tmp / "run")
    fit(cfg)
    return tmp / "run"


STATISTICS = ("rmse", "mean", "median", "std", "min", "max")


def _evo_scores(gt_file: Path, est_file: Path) -> dict:
    """APE and RPE (delta 1 frame, consecutive pairs, no alignment) of two KITTI pose files scored by evo
    alone: ``{"ape" | "rpe": {"trans" | "rot_rad": {statistic: value}}}``."""
    ref = file_interface.read_kitti_poses_file(str(gt_file))
    est = file_interface.read_kitti_poses_file(str(est_file))
    scores: dict = {"ape": {}, "rpe": {}}
    for kind, relation in (
        ("trans", PoseRelation.translation_part),
        ("rot_rad", PoseRelation.rotation_angle_rad),
    ):
        ape = APE(relation)
        rpe = RPE(relation, delta=1, delta_unit=Unit.frames, all_pairs=False)
        for part, metric in (("ape", ape), ("rpe", rpe)):
            metric.process_data((ref, est))
            scores[part][kind] = metric.get_all_statistics()
    return scores


def _check_outputs(run: Path, tiny_kitti: Path) -> dict:
    """The run's results.json, trajectories and plots; every APE / RPE number equal to evo's score of the
    written trajectory file against the ground-truth pose file."""
    result = json.loads((run / "results.json").read_text())
    gt_file = tiny_kitti / "poses" / "02.txt"
    gt = read_poses(gt_file)
    assert set(result["sequences"]) == {"02"}
    assert result["loss"] == {"class": "QuaternionLoss", "k": 400.0}  # matched: 100 / (1/4)
    entry = result["sequences"]["02"]
    traj = run / "trajectories" / "02.txt"
    est = read_poses(traj)
    evo_poses = file_interface.read_kitti_poses_file(str(traj))
    assert evo_poses.num_poses == len(gt) == len(est)
    np.testing.assert_allclose(evo_poses.poses_se3[0], gt[0], atol=1e-8)
    expected = _evo_scores(gt_file, traj)
    for part in ("ape", "rpe"):
        for kind in ("trans", "rot_rad"):
            assert set(entry[part][kind]) == set(STATISTICS)
            for stat, value in entry[part][kind].items():
                assert math.isfinite(value)
                reference = expected[part][kind][stat]
                assert value == pytest.approx(reference, rel=1e-9, abs=1e-12), (part, kind, stat)
    assert entry["ape"]["trans"]["max"] > 0 and entry["rpe"]["rot_rad"]["max"] > 0  # not a trivial estimate
    assert entry["kitti"]["t_err_pct"] is None and "note" in entry["kitti"]  # 10 frames: no 100 m segment
    assert result["overall"]["ape"]["trans"]["rmse"] == pytest.approx(entry["ape"]["trans"]["rmse"])
    assert (run / "plots" / "02.png").stat().st_size > 1000
    check_ape_against_evo(run / "trajectories", "02", entry["ape"]["trans"]["rmse"], len(gt))
    return result


@pytest.mark.slow
def test_training_writes_results_trajectories_and_plots(trained_run: Path, tiny_kitti: Path) -> None:
    result = _check_outputs(trained_run, tiny_kitti)
    assert result["checkpoint"] == str(trained_run / "checkpoints" / "best.ckpt")
    header, *rows = list(csv.reader((trained_run / "metrics.csv").open()))
    for key in ("val/ape_trans_rmse", "val/rpe_trans_rmse", "val/rpe_rot_rmse"):
        assert key in header
        values = [row[header.index(key)] for row in rows if row[header.index(key)]]
        assert values and all(math.isfinite(float(v)) for v in values)
    assert "val/kitti_t_err" not in header  # no segment: not logged, never 0


@pytest.mark.slow
def test_eval_cli_writes_the_same_files(
    trained_run: Path, tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:  # fmt: skip
    """The eval entry in process (tests/test_checkpoints.py runs the real command line): its results.json
    holds evo's APE / RPE of the trajectory it writes, and that trajectory is the one training wrote."""
    data = [o for o in tiny_overrides(tiny_kitti, trained_run.parent / "cache") if o.startswith("data")]
    out = tmp_path / "eval"
    ckpt = trained_run / "checkpoints" / "best.ckpt"
    status, err = eval_main(
        [f"ckpt_path={ckpt}", *data, "device=cpu", f"hydra.run.dir={out}"], monkeypatch, capsys
    )
    assert status == 0, err
    _check_outputs(out, tiny_kitti)  # against evo
    assert (out / "trajectories" / "02.txt").read_text() == (
        trained_run / "trajectories" / "02.txt"
    ).read_text()


def test_eval_cli_errors_are_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    out = f"hydra.run.dir={tmp_path / 'eval'}"
    missing = tmp_path / "nope" / "best.ckpt"
    status, err = eval_main([f"ckpt_path={missing}", out], monkeypatch, capsys)
    assert status == 2 and err.strip() == f"error: checkpoint not found: {missing}"
    garbage = tmp_path / "garbage.ckpt"
    garbage.write_bytes(b"not a checkpoint")
    status, err = eval_main([f"ckpt_path={garbage}", out], monkeypatch, capsys)
    assert status == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith(f"error: {garbage}: cannot load")
    status, err = eval_main([out], monkeypatch, capsys)
    assert status == 2 and err.strip() == "error: ckpt_path is required: python -m lossvo.eval ckpt_path=PATH"


@pytest.mark.slow
def test_sequence_without_ground_truth(trained_run: Path, kitti_copy: Path, tmp_path: Path) -> None:
    network = load_network(trained_run / "checkpoints" / "best.ckpt")
    next(kitti_copy.rglob("poses/02.txt")).unlink()  # sequence 02 without its ground truth (a test split)
    from hydra.utils import instantiate

    overrides = [*tiny_overrides(kitti_copy, trained_run.parent / "cache"), "data.splits.val=[01]"]
    cfg = compose_train(overrides, tmp_path / "x")
    datamodule = instantiate(cfg.data, _convert_="all")
    result = evaluate_run(network, datamodule, tmp_path, ["02"])
    assert result.sequences["02"].note is not None and result.sequences["02"].scores is None
    assert result.overall.note is not None and result.overall.scores is None
    np.testing.assert_allclose(read_poses(tmp_path / "trajectories" / "02.txt")[0], np.eye(4), atol=1e-12)


def test_trajectory_validation_skips_datamodules_without_sequences() -> None:
    from types import SimpleNamespace

    from lossvo.training.callbacks import TrajectoryValidation

    class NoLog:
        def log(self, *args, **kwargs):
            raise AssertionError("nothing should be logged")

    trainer = SimpleNamespace(sanity_checking=False, current_epoch=0, datamodule=object())
    TrajectoryValidation().on_validation_epoch_end(trainer, NoLog())
    trainer = SimpleNamespace(sanity_checking=False, current_epoch=0, datamodule=None)
    TrajectoryValidation().on_validation_epoch_end(trainer, NoLog())
    with pytest.raises(UserError, match="every_n_epochs"):
        TrajectoryValidation(every_n_epochs=0)


@pytest.mark.parametrize("carry_state", [False, True])
def test_predict_sequence_cuts_windows_at_gaps(carry_state: bool) -> None:
    """Windows tiled between gaps, the pair across a gap alone: still every pair once, in order."""
    n = 20
    relative = _random_poses(n)
    stub = PairStub(relative)
    if carry_state:  # DeepVO's forward_with_state, through the stub
        stub.model = type(
            "Model", (), {"forward_with_state": lambda self, x, state: (stub({"frames": x}), state)}
        )()
    frames = np.broadcast_to(np.arange(n, dtype=np.uint8)[:, None, None, None], (n, 3, 4, 5))
    gap = np.zeros(n - 1, dtype=bool)
    gap[[6, 13]] = True
    out = predict_sequence(
        stub, {"frames": frames}, _float, 5, batch_windows=2, gap=gap, carry_state=carry_state
    )
    np.testing.assert_array_equal(out, relative.numpy())
    windows = [tuple(w) for w in tile(n, 5, gap)]
    assert (6, 8) in windows and (13, 15) in windows


def test_eval_help_lists_only_the_data_group() -> None:
    """``lossvo.eval --help`` names the one group eval reads (every option it names exists), none of
    training's (loss, model, trainer, ...)."""
    done = subprocess.run([sys.executable, "-m", "lossvo.eval", "--help"], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    groups = done.stdout.split("== Configuration group ==")[1].split("==")[0].strip().splitlines()
    assert len(groups) == 1 and groups[0].startswith("data: ")
    conf = Path(lossvo_eval.CONFIG_DIR) / "data"
    assert all((conf / f"{name}.yaml").is_file() for name in groups[0].removeprefix("data: ").split(", "))
    assert "trainer:" not in done.stdout and "loss: " not in done.stdout
