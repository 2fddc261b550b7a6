"""``loss.translation``: the metric term unchanged, the direction-only term (scale invariance, zero at the
true direction, calibration, the standing-car mask, t = 0), the yardstick and evaluation with steps scaled
to the ground-truth step lengths, results.json's record, a training run with loss.translation=direction."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from torch import Tensor

from helpers import fit
from lossvo import geometry as g
from lossvo.console import UserError
from lossvo.data.kitti import read_poses
from lossvo.evaluation.checkpoints import load_network
from lossvo.evaluation.job_folder import TRANSLATION_METRIC, TRANSLATION_SCALED, JobFolderError, Results
from lossvo.evaluation.results import PooledScores, predict_and_score
from lossvo.evaluation.trajectories import integrate, scale_steps
from lossvo.losses import DIRECTION_WEIGHT_M2, MIN_STEP_M, EulerLoss, PoseLoss
from test_eval import PairStub, _float
from test_losses import CONF, LOSSES
from test_train import compose_train, tiny_overrides


def moving_targets(B: int = 3, T: int = 4, seed: int = 0) -> Tensor:
    """(B, T, 4, 4) float64 relative poses: rotations up to ~0.6 rad, steps of 0.3 to 1.5 m."""
    gen = torch.Generator().manual_seed(seed)
    R = g.so3_exp(0.3 * torch.randn(B, T, 3, generator=gen, dtype=torch.float64))
    t = torch.randn(B, T, 3, generator=gen, dtype=torch.float64)
    t = (
        t
        / t.norm(dim=-1, keepdim=True)
        * (0.3 + 1.2 * torch.rand(B, T, 1, generator=gen, dtype=torch.float64))
    )
    return g.make_pose(R, t)


def predictions(cls: type[PoseLoss], target: Tensor, seed: int = 1) -> Tensor:
    """Outputs (..., cls.dim) that decode to poses near ``target``, of another step length and direction."""
    gen = torch.Generator().manual_seed(seed)
    shape = target.shape[:-2]
    noise = g.so3_exp(0.1 * torch.randn(*shape, 3, generator=gen, dtype=torch.float64))
    t = target[..., :3, 3] * (0.5 + torch.rand(*shape, 1, generator=gen, dtype=torch.float64))
    t = t + 0.3 * torch.randn(*shape, 3, generator=gen, dtype=torch.float64)
    return cls().encode(g.make_pose(target[..., :3, :3] @ noise, t))


def unit(v: Tensor) -> Tensor:
    return v / v.norm(dim=-1, keepdim=True)


# -- the metric term (the default) is unchanged ------------------------------------------------------


@pytest.mark.parametrize("cls", LOSSES)
def test_metric_default_is_the_previous_formula_bit_for_bit(cls: type[PoseLoss]) -> None:
    target = moving_targets().float()
    pred = predictions(cls, target.double()).float()
    default, metric = cls(), cls(translation="metric")
    assert default.translation == "metric"
    R, t = default.decode_rt(pred)
    trans_sq = (t - target[..., :3, 3]).square().sum(-1)  # the formula before the option existed
    rot = default.rotation_term(pred, R, target[..., :3, :3])
    assert default.k is not None
    expected = {
        "loss": trans_sq.mean() + default.k * rot.mean(),
        "trans_loss": trans_sq.mean(),
        "rot_loss": rot.mean(),
        "trans_err_m": torch.sqrt(trans_sq).mean(),
        "rot_err_rad": g.so3_geodesic_distance(target[..., :3, :3], R).mean(),
    }
    for out in (default(pred, target), metric(pred, target)):
        assert set(out) == set(expected)
        for key, value in expected.items():
            assert torch.equal(out[key], value), key


# -- the direction term ------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", LOSSES)
def test_direction_term_is_invariant_to_scaling_the_predicted_translation(cls: type[PoseLoss]) -> None:
    loss, target = cls(translation="direction"), moving_targets()
    pred = predictions(cls, target)
    reference = loss(pred, target)
    assert reference["trans_loss"] > 1e-3  # not trivially zero
    assert cls().decode_rt(pred)[1].norm(dim=-1).min() * 0.05 > MIN_STEP_M  # every length above the floor
    for factor in (0.05, 0.5, 3.0, 250.0):
        scaled = pred.clone()
        scaled[..., :3] *= factor  # t, or rho for SE(3), where t = V(omega) rho scales with rho
        out = loss(scaled, target)
        for key in ("trans_loss", "rot_loss", "loss", "trans_err_m"):
            torch.testing.assert_close(out[key], reference[key], rtol=1e-12, atol=1e-12)
    metric = cls()(pred, target)["trans_loss"]
    scaled = pred.clone()
    scaled[..., :3] *= 3.0
    assert not torch.isclose(cls()(scaled, target)["trans_loss"], metric)  # the metric term is not


@pytest.mark.parametrize("cls", LOSSES)
def test_direction_term_is_zero_at_the_true_direction_with_any_length(cls: type[PoseLoss]) -> None:
    loss, target = cls(translation="direction"), moving_targets()
    R, t = target[..., :3, :3], target[..., :3, 3]
    for length in (0.01, 1.0, 40.0):
        out = loss(loss.encode(g.make_pose(R, unit(t) * length)), target)
        torch.testing.assert_close(
            out["trans_loss"], torch.zeros((), dtype=torch.float64), atol=1e-12, rtol=0
        )
        torch.testing.assert_close(
            out["trans_err_m"], torch.zeros((), dtype=torch.float64), atol=1e-9, rtol=0
        )
    out = loss(loss.encode(g.make_pose(R, -3.0 * t)), target)  # the opposite direction: |2u^|^2 = 4
    torch.testing.assert_close(
        out["trans_loss"], torch.tensor(4.0 * DIRECTION_WEIGHT_M2, dtype=torch.float64)
    )


def test_direction_term_is_the_metric_term_of_a_1m_step_with_the_same_direction_error() -> None:
    """The calibration: 1 m^2 * |u - u^|^2 = 2 - 2 cos(alpha) m^2 = the metric term of a 1 m step of the right
    length rotated by alpha, ~ alpha^2 at small alpha (whatever lengths the two steps have)."""
    direction, metric = EulerLoss(translation="direction"), EulerLoss()
    for alpha in (1e-3, 0.05, 0.4):
        turned = (math.sin(alpha), 0.0, math.cos(alpha))
        target = g.make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 2.5]))[None, None]
        pred = torch.tensor([[[7.0 * turned[0], 0.0, 7.0 * turned[2], 0.0, 0.0, 0.0]]], dtype=torch.float64)
        one_metre = target.clone()
        one_metre[..., :3, 3] = torch.tensor([0.0, 0.0, 1.0])
        unit_pred = pred.clone()
        unit_pred[..., :3] /= 7.0
        value = direction(pred, target)["trans_loss"]
        torch.testing.assert_close(value, metric(unit_pred, one_metre)["trans_loss"], rtol=1e-9, atol=1e-15)
        torch.testing.assert_close(value, torch.tensor(2 - 2 * math.cos(alpha), dtype=torch.float64))
        assert abs(value.item() / alpha**2 - 1) < alpha**2 / 12 + 1e-9  # 2 - 2 cos a = a^2 - a^4 / 12 + ...


@pytest.mark.parametrize("cls", LOSSES)
def test_standing_car_pairs_have_no_translation_term_and_count_in_the_mean(cls: type[PoseLoss]) -> None:
    target = moving_targets(1, 6)
    lengths = torch.tensor(
        [0.0, 0.5 * MIN_STEP_M, 0.99 * MIN_STEP_M, 2 * MIN_STEP_M, 0.8, 1.3], dtype=torch.float64
    )
    target[..., :3, 3] = unit(target[..., :3, 3]) * lengths[None, :, None]
    loss = cls(translation="direction")
    pred = predictions(cls, target).requires_grad_()
    out = loss(pred, target)
    _, t = loss.decode_rt(pred.detach())
    per_pair = (unit(t) - unit(target[..., :3, 3])).square().sum(-1)[0]
    moving = lengths >= MIN_STEP_M
    assert moving.tolist() == [False, False, False, True, True, True]
    expected = per_pair[moving].sum() / len(lengths)  # masked pairs are 0, the mean is over all 6 pairs
    torch.testing.assert_close(out["trans_loss"], DIRECTION_WEIGHT_M2 * expected, rtol=1e-12, atol=0)
    out["trans_loss"].backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all()
    assert (pred.grad[0, ~moving, :3] == 0).all() and (pred.grad[0, moving, :3] != 0).any(-1).all()


@pytest.mark.parametrize("cls", LOSSES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_zero_predicted_translation_has_a_finite_value_and_gradient(cls: type[PoseLoss], dtype) -> None:
    """The heads start from the identity (t = 0); the gradient there points t at the target's direction."""
    loss, target = cls(translation="direction"), moving_targets(2, 3).to(dtype)
    pred = loss.identity_output().to(dtype).expand(2, 3, -1).clone().requires_grad_()
    assert (loss.decode_rt(pred)[1] == 0).all()
    out = loss(pred, target)
    assert all(torch.isfinite(value) for value in out.values())
    out["loss"].backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all()
    step = -pred.grad[..., :3]  # t = rho at omega = 0 for SE(3)
    cosine = (unit(step) * unit(target[..., :3, 3])).sum(-1)
    torch.testing.assert_close(cosine, torch.ones_like(cosine), rtol=0, atol=1e-5)
    assert step.norm(dim=-1).max() <= 2 * DIRECTION_WEIGHT_M2 / MIN_STEP_M / 6 * 1.0001  # 2 w / floor / pairs


@pytest.mark.parametrize("cls", LOSSES)
def test_direction_yardstick_scales_each_step_to_the_ground_truth_length(cls: type[PoseLoss]) -> None:
    target = moving_targets()
    pred = predictions(cls, target)
    out = cls(translation="direction")(pred, target)
    _, t = cls().decode_rt(pred)
    t_np, t_gt = t.numpy(), target[..., :3, 3].numpy()
    scaled = (
        t_np / np.linalg.norm(t_np, axis=-1, keepdims=True) * np.linalg.norm(t_gt, axis=-1, keepdims=True)
    )
    np.testing.assert_allclose(
        out["trans_err_m"].item(), np.linalg.norm(scaled - t_gt, axis=-1).mean(), rtol=1e-12
    )
    assert not torch.isclose(out["trans_err_m"], cls()(pred, target)["trans_err_m"])
    torch.testing.assert_close(out["rot_err_rad"], cls()(pred, target)["rot_err_rad"], rtol=0, atol=0)


@pytest.mark.parametrize("cls", LOSSES)
@pytest.mark.parametrize("bad", ["foo", "Metric", "", None, 1, ["metric"]])
def test_bad_translation_is_one_line_at_construction(cls: type[PoseLoss], bad: object) -> None:
    with pytest.raises(UserError) as caught:
        cls(translation=bad)
    assert str(caught.value) == f"loss.translation: expected one of metric, direction, cue, got {bad!r}"


@pytest.mark.parametrize("name", ["euler", "quat", "chordal", "geodesic", "sixd", "svd", "quat10d"])
def test_every_loss_config_says_cue_and_takes_metric_and_direction(name: str) -> None:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose("train", overrides=[f"loss={name}"])
        chosen = {
            value: instantiate(compose("train", overrides=[f"loss={name}", f"loss.translation={value}"]).loss)
            for value in ("metric", "direction")
        }
    assert cfg.loss.translation == "cue" and instantiate(cfg.loss).translation == "cue"
    assert {value: loss.translation for value, loss in chosen.items()} == {
        "metric": "metric",
        "direction": "direction",
    }


# -- evaluation: steps scaled to the ground-truth step lengths ---------------------------------------


def ground_truth(n: int = 9, seed: int = 3) -> Tensor:
    """(n, 4, 4) float64 camera-to-world poses with one standing step (length 0)."""
    gen = torch.Generator().manual_seed(seed)
    R = g.so3_exp(0.05 * torch.randn(n - 1, 3, generator=gen, dtype=torch.float64))
    t = torch.randn(n - 1, 3, generator=gen, dtype=torch.float64)
    t[2] = 0.0
    return integrate(g.make_pose(R, t), start=g.make_pose(torch.eye(3, dtype=torch.float64), torch.ones(3)))


def step_lengths(poses: Tensor) -> Tensor:
    return g.consecutive_relative_poses(poses)[:, :3, 3].norm(dim=-1)


def test_scaled_steps_have_the_ground_truth_lengths_and_the_predicted_directions() -> None:
    gt = ground_truth()
    reference = g.consecutive_relative_poses(gt)
    gen = torch.Generator().manual_seed(5)
    predicted = g.make_pose(g.so3_exp(0.05 * torch.randn(8, 3, generator=gen, dtype=torch.float64)),
                            7.0 * torch.randn(8, 3, generator=gen, dtype=torch.float64))  # fmt: skip
    predicted[4, :3, 3] = 0.0  # no direction: a step straight ahead (+z), as the ORB+E baseline
    scaled = scale_steps(predicted, reference)
    trajectory = integrate(scaled, start=gt[0])
    torch.testing.assert_close(step_lengths(trajectory), step_lengths(gt), rtol=1e-9, atol=1e-12)
    assert not torch.allclose(step_lengths(integrate(predicted, start=gt[0])), step_lengths(gt))
    torch.testing.assert_close(scaled[..., :3, :3], predicted[..., :3, :3], rtol=0, atol=0)
    moving = torch.tensor([k not in (2, 4) for k in range(8)])
    cosine = (unit(scaled[moving, :3, 3]) * unit(predicted[moving, :3, 3])).sum(-1)
    torch.testing.assert_close(cosine, torch.ones_like(cosine))
    length = reference[4, :3, 3].norm()
    torch.testing.assert_close(scaled[4, :3, 3], torch.stack([0 * length, 0 * length, length]))
    assert scaled[2, :3, 3].norm() < 1e-12  # the standing step stays standing


@pytest.mark.parametrize("translation", ["metric", "direction"])
def test_predict_and_score_scales_the_steps_of_a_direction_network_only(translation: str) -> None:
    """The evaluation path (validation during training and evaluate_run): a network whose outputs decode
    to steps 3x too long is scored on the true lengths only when its loss is direction-only."""
    gt = ground_truth()
    relative = g.consecutive_relative_poses(gt)
    relative[..., :3, 3] *= 3.0
    relative[..., :3, :3] = relative[..., :3, :3] @ g.so3_exp(
        torch.tensor([0.0, 0.02, 0.0], dtype=torch.float64)
    )
    stub = PairStub(relative)
    stub.loss = EulerLoss(translation=translation)
    frames = torch.arange(len(gt), dtype=torch.uint8)[:, None, None, None].expand(-1, 3, 2, 2)
    times = np.arange(len(gt)) / 10.0
    datamodule = SimpleNamespace(sequence_inputs=lambda name: {"frames": frames}, prepare=_float, seq_len=3,
                                 sequence_times=lambda name: times)  # fmt: skip
    trajectory, scores = predict_and_score(stub, datamodule, "00", gt.numpy(), PooledScores())
    assert scores is not None and math.isfinite(scores["ape"]["trans"]["rmse"])
    factor = 1.0 if translation == "direction" else 3.0
    torch.testing.assert_close(step_lengths(trajectory), factor * step_lengths(gt), rtol=1e-9, atol=1e-12)


def test_results_json_records_and_checks_the_translation(tmp_path: Path) -> None:
    from test_report import contract_example

    results = contract_example(tmp_path)
    assert results.translation == TRANSLATION_METRIC
    path = tmp_path / "results.json"
    for value in (TRANSLATION_METRIC, TRANSLATION_SCALED):
        replace(results, translation=value).write(path)
        assert json.loads(path.read_text())["translation"] == value
        assert Results.read(path).translation == value
    content = json.loads(path.read_text())
    content["translation"] = "direction"
    path.write_text(json.dumps(content))
    with pytest.raises(JobFolderError, match=r"translation: expected 'metric' or 'direction \(scaled"):
        Results.read(path)
    del content["translation"]
    path.write_text(json.dumps(content))
    with pytest.raises(JobFolderError, match="translation is missing"):
        Results.read(path)


# -- a training run ------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_direction_run_records_it_and_is_scored_with_ground_truth_step_lengths(
    tiny_kitti: Path, tmp_path: Path
) -> None:
    overrides = [
        *tiny_overrides(tiny_kitti, tmp_path / "cache"),
        "loss=chordal",
        "loss.translation=direction",
        "trainer.max_epochs=1",
        "+trainer.limit_train_batches=2",
    ]
    run = tmp_path / "run"
    metrics = fit(compose_train(overrides, run))
    assert all(math.isfinite(v) for v in metrics.values()) and "val/score" in metrics
    results = Results.read(run / "results.json")
    assert results.translation == TRANSLATION_SCALED
    assert json.loads((run / "results.json").read_text())["translation"] == TRANSLATION_SCALED
    network = load_network(run / "checkpoints" / "best.ckpt")
    assert network.loss.translation == "direction"
    gt = torch.from_numpy(read_poses(next(tiny_kitti.rglob("poses/02.txt"))))
    trajectory = torch.from_numpy(read_poses(run / "trajectories" / "02.txt"))
    torch.testing.assert_close(step_lengths(trajectory), step_lengths(gt), rtol=1e-6, atol=1e-6)
    from lossvo.report.jobs import load_job

    status = json.loads((run / "status.json").read_text())  # fit() trains in process: no lifecycle end
    (run / "status.json").write_text(json.dumps({**status, "status": "completed"}))
    note = f"translation scored as {TRANSLATION_SCALED}: no metric scale, as ORB+E's"
    assert note in load_job(run).notes  # the report's jobs table says so
