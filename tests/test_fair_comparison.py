"""A fair comparison: same start for every loss, one selection rule, calibrated weights (bad weighting
configs: the rows of docs/bad-input.md, tests/test_bad_input.py).

For one seed every configuration must get identical backbone weights, identical training windows in the
same order and the same random stream afterwards (dropout masks); only the head may differ. Under
``weighting=matched`` every loss weighs a small rotation error theta as ``c * theta^2``.
"""

from __future__ import annotations

import math
from pathlib import Path

import lightning as L
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from helpers import fit
from lossvo import geometry as g
from lossvo.train import CONFIG_DIR
from lossvo.training import fitting, resolvers
from lossvo.training.module import VOModule
from lossvo.training.selection import SelectionScore, selection_score
from lossvo.weighting import HomoscedasticWeighting
from test_train import compose_train, tiny_overrides

ALL_LOSSES = ("euler", "quat", "chordal", "geodesic", "sixd", "svd", "quat10d")
COMPARED = ("euler", "quat", "chordal", "svd")


def built(root: Path, tmp: Path, loss: str, *extra: str) -> tuple[VOModule, torch.Tensor, list]:
    """(module, the global RNG state after building, the first two training batches) at seed 0."""
    cfg = compose_train([*tiny_overrides(root, tmp / "cache"), f"loss={loss}", "seed=0", *extra], tmp / loss)
    L.seed_everything(cfg.seed, workers=True)
    datamodule, module, _ = fitting.build(cfg)
    state = torch.get_rng_state()
    datamodule.prepare_data()
    datamodule.setup("fit")
    batches = [b for _, b in zip(range(2), datamodule.train_dataloader(), strict=False)]
    return module, state, batches


def backbone(module: VOModule) -> dict[str, torch.Tensor]:
    return {k: v for k, v in module.model.state_dict().items() if not k.startswith("head.")}


@pytest.mark.slow
def test_same_start_for_every_loss(tiny_kitti: Path, tmp_path: Path) -> None:
    reference, ref_state, ref_batches = built(tiny_kitti, tmp_path, "euler")
    ref_backbone = backbone(reference)
    assert len(ref_backbone) > 20
    for loss in COMPARED[1:]:
        module, state, batches = built(tiny_kitti, tmp_path, loss)
        weights = backbone(module)
        assert weights.keys() == ref_backbone.keys()
        for key, value in ref_backbone.items():
            assert torch.equal(weights[key], value), f"{loss}: {key} differs from euler's"
        assert torch.equal(state, ref_state), f"{loss}: the random stream after building differs"
        for batch, ref in zip(batches, ref_batches, strict=True):
            assert torch.equal(batch["frames"], ref["frames"]) and torch.equal(
                batch["targets"], ref["targets"]
            )
        assert module.model.head.out_features == resolvers.dim_of(module.hparams.loss["_target_"])


@pytest.mark.slow
def test_weighting_shifts_no_stream(tiny_kitti: Path, tmp_path: Path) -> None:
    _, matched, batches = built(tiny_kitti, tmp_path, "quat")
    module, learned, other = built(tiny_kitti, tmp_path / "learned", "quat", "weighting=learned")
    assert torch.equal(matched, learned)
    assert all(torch.equal(a["frames"], b["frames"]) for a, b in zip(batches, other, strict=True))
    assert isinstance(module.loss.weighting, HomoscedasticWeighting)


@pytest.mark.slow
def test_another_seed_is_another_start(tiny_kitti: Path, tmp_path: Path) -> None:
    a, _, _ = built(tiny_kitti, tmp_path, "euler")
    b, _, _ = built(tiny_kitti, tmp_path / "s1", "euler", "seed=1")
    assert not torch.equal(a.model.encoder.conv1[0].weight, b.model.encoder.conv1[0].weight)


# -- weights ----------------------------------------------------------------------------------------


def compose_loss(loss: str, *extra: str) -> torch.nn.Module:
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("train", overrides=[f"loss={loss}", *extra])
    return instantiate(cfg.loss)


def rotated(R: torch.Tensor, theta: float, axis: tuple[float, float, float]) -> torch.Tensor:
    omega = torch.tensor(axis, dtype=torch.float64)
    return R @ g.so3_exp(omega / omega.norm() * theta)


@pytest.mark.slow
@pytest.mark.parametrize("loss_name", ALL_LOSSES)
@pytest.mark.parametrize("c", [100.0, 30.0])
def test_matched_weights_make_every_rotation_term_c_theta_squared(loss_name: str, c: float) -> None:
    loss = compose_loss(loss_name, f"weighting.c={c}")
    theta = 1e-3
    targets = [torch.eye(3, dtype=torch.float64), g.euler_to_matrix(torch.tensor([0.3, 0.0, 0.02]).double())]
    for R_target in targets:
        for axis in ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.3, -0.5, 0.8)):
            t = torch.tensor([0.1, -0.2, 1.0], dtype=torch.float64)
            target = g.make_pose(R_target, t)[None, None]
            pred = loss.encode(g.make_pose(rotated(R_target, theta, axis), t))[None, None]
            out = loss(pred, target)
            assert out["trans_loss"].item() < 1e-20
            assert out["loss"].item() / theta**2 == pytest.approx(c, rel=0.01), (loss_name, axis)


def test_paper_weights_are_the_study_s() -> None:
    assert [compose_loss(n, "weighting=paper").k for n in ("euler", "quat", "chordal")] == [
        100.0,
        14.0,
        153.0,
    ]


def test_explicit_k_wins_and_the_logged_config_shows_it() -> None:
    assert compose_loss("quat", "loss.k=7").k == 7.0
    assert compose_loss("quat", "weighting=paper", "loss.k=7").k == 7.0
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("train", overrides=["loss=quat"])
    assert OmegaConf.to_container(cfg.loss, resolve=True)["k"] == 400.0  # the loss alone: no Hydra run


def test_unsquared_quaternion_distance() -> None:
    loss = compose_loss("quat", "loss.squared=false", "weighting=paper")
    assert loss.k == 14.0 and not loss.squared
    eye, zero = torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
    target = g.make_pose(eye, zero)[None, None]
    pred = loss.encode(g.make_pose(rotated(eye, 0.2, (0, 0, 1)), zero))[None, None]
    out = loss(pred, target)
    assert out["rot_loss"].item() == pytest.approx(2 * math.sin(0.05))  # |q - q^| = 2 sin(theta / 4)
    exact = loss.encode(target).clone().requires_grad_()
    (grad,) = torch.autograd.grad(loss(exact, target)["loss"], exact)  # zero error: the norm's kink
    assert torch.isfinite(grad).all()
    with pytest.raises(Exception, match=r"loss\.squared=false.*no matched k"):
        compose_loss("quat", "loss.squared=false")


# -- learned weights --------------------------------------------------------------------------------


def test_learned_weights_get_gradients() -> None:
    weighting = HomoscedasticWeighting(0.5, -0.5)
    loss = weighting(torch.tensor(2.0), torch.tensor(0.1))
    expected = math.exp(-0.5) * 2.0 + 0.5 + math.exp(0.5) * 0.1 - 0.5
    assert loss.item() == pytest.approx(expected)
    loss.backward()
    assert weighting.log_vars.grad is not None
    torch.testing.assert_close(
        weighting.log_vars.grad, torch.tensor([1 - math.exp(-0.5) * 2.0, 1 - math.exp(0.5) * 0.1])
    )


@pytest.mark.slow
def test_learned_weights_move_and_reload(tiny_kitti: Path, tmp_path: Path) -> None:
    overrides = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), "loss=quat", "weighting=learned",
                 "weighting.learned.s_r=1.0", "trainer.max_epochs=2", "optimizer.lr=0.05"]  # fmt: skip
    cfg = compose_train(overrides, tmp_path / "run")
    metrics = fit(cfg)
    assert {"train/s_t", "train/s_r"} <= set(metrics)
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    module = VOModule.load_from_checkpoint(last, map_location="cpu", weights_only=True)
    s_t, s_r = module.loss.weighting.log_vars.tolist()
    assert abs(s_t - 0.0) > 1e-3 and abs(s_r - 1.0) > 1e-3, (s_t, s_r)
    assert module.loss.k is None
    assert torch.load(last, map_location="cpu")["state_dict"]["loss.weighting.log_vars"].tolist() == [
        s_t,
        s_r,
    ]
    header = (tmp_path / "run" / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"train/s_t", "train/s_r"} <= set(header)


# -- one selection rule -----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("loss", ALL_LOSSES)
def test_checkpoint_monitor_is_the_same_for_every_loss(tiny_kitti: Path, tmp_path: Path, loss: str) -> None:
    cfg = compose_train([*tiny_overrides(tiny_kitti, tmp_path), f"loss={loss}"], tmp_path / "run")
    _, module, trainer = fitting.build(cfg)
    monitors = {c.monitor for c in trainer.checkpoint_callbacks}
    assert monitors == {"val/score", None} and cfg.optimized_metric == "val/score"  # best, and last
    assert module.hparams.monitor == "val/score"
    paper = compose_train([*tiny_overrides(tiny_kitti, tmp_path), f"loss={loss}", "selection=loss"], tmp_path)
    assert paper.callbacks.model_checkpoint.monitor == "val/loss" == paper.optimized_metric


def test_selection_score_is_relative_to_no_motion() -> None:
    gen = torch.Generator().manual_seed(0)
    R = g.so3_exp(0.05 * torch.randn(3, 5, 3, generator=gen, dtype=torch.float64))
    target = g.make_pose(R, torch.randn(3, 5, 3, generator=gen, dtype=torch.float64))
    identity = torch.eye(4, dtype=torch.float64).expand_as(target)
    assert selection_score(target, target).item() == pytest.approx(0.0, abs=1e-7)
    assert selection_score(identity, target).item() == pytest.approx(1.0)
    # Hand-computed: translation error halved, rotation exact -> (0.5 + 0) / 2.
    half = target.clone()
    half[..., :3, 3] *= 0.5
    assert selection_score(half, target).item() == pytest.approx(0.25)
    metric = SelectionScore()
    metric.update(half[:1], target[:1])
    metric.update(half[1:], target[1:])
    assert metric.compute().item() == pytest.approx(0.25, rel=1e-6)
