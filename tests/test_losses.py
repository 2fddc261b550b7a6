"""lossvo.losses: zero at the target, hand-computed values, gradients, sign invariance, bad input."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from scipy.spatial.transform import Rotation

from lossvo import geometry as g
from lossvo.console import UserError
from lossvo.data import specs  # noqa: F401  (stores the data schema the composed config's defaults name)
from lossvo.losses import (
    ChordalLoss,
    EulerLoss,
    GeodesicLoss,
    PoseLoss,
    QuaternionLoss,
    SixDLoss,
    SVDLoss,
    SymMatrixQuatLoss,
)
from lossvo.training import resolvers

CONF = Path(__file__).resolve().parents[1] / "src" / "lossvo" / "conf"
resolvers.register()  # the loss and weighting configs interpolate them
LOSSES = [EulerLoss, QuaternionLoss, ChordalLoss, GeodesicLoss, SixDLoss, SVDLoss, SymMatrixQuatLoss]
KEYS = {"loss", "trans_loss", "rot_loss", "trans_err_m", "rot_err_rad"}
NEAR_PI = math.radians(179.9)


def targets(
    B: int = 4, T: int = 5, seed: int = 0, max_angle: float = NEAR_PI, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """(B, T, 4, 4) relative poses: random rotations up to ``max_angle``, plus identity."""
    gen = torch.Generator().manual_seed(seed)
    axis = torch.randn(B, T, 3, generator=gen, dtype=torch.float64)
    angle = max_angle * torch.rand(B, T, 1, generator=gen, dtype=torch.float64)
    angle[0, 0] = 0.0
    angle[0, 1] = max_angle
    R = g.so3_exp(axis / axis.norm(dim=-1, keepdim=True) * angle)
    t = torch.randn(B, T, 3, generator=gen, dtype=torch.float64)
    return g.make_pose(R, t).to(dtype)


def pose(R: torch.Tensor, t: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> torch.Tensor:
    """(1, 1, 4, 4) float64 pose from a 3x3 rotation and a translation."""
    return g.make_pose(R, torch.tensor(t, dtype=torch.float64))[None, None]


def rot(axis: int, angle: float) -> torch.Tensor:
    omega = torch.zeros(3, dtype=torch.float64)
    omega[axis] = angle
    return g.so3_exp(omega)


def independent_encoding(cls: type[PoseLoss], target: torch.Tensor) -> torch.Tensor:
    """A network output (..., cls.dim) that decodes to ``target`` (..., 4, 4), computed from the
    parameterisations' definitions with scipy (not with lossvo's geometry or roma, which it uses):

    - euler: (t, yaw, pitch, roll) with R = Ry(yaw) Rx(pitch) Rz(roll), scipy's intrinsic "YXZ";
    - quat: (t, w, x, y, z) with w >= 0;
    - chordal: xi = (rho, omega), the 4x4 matrix logarithm of the pose (scipy.linalg.logm), so that
      R = exp(omega^) and t = V(omega) rho;
    - geodesic: (t, rotation vector); sixd: (t, first column, second column);
    - svd: (t, M) with M = R diag(1, 2, 3) row-major, whose nearest rotation (polar factor) is R;
    - quat10d: (t, upper triangle of A = I - q q^T in roma's order), q = (x, y, z, w) A's null vector.
    """
    T = target.detach().to(torch.float64).reshape(-1, 4, 4).numpy()
    R, t = T[:, :3, :3], T[:, :3, 3]
    rotation = Rotation.from_matrix(R)
    if cls is EulerLoss:
        r = rotation.as_euler("YXZ")
    elif cls is QuaternionLoss:
        xyzw = rotation.as_quat()
        r = np.where(xyzw[:, 3:] < 0, -xyzw, xyzw)[:, [3, 0, 1, 2]]
    elif cls is ChordalLoss:
        T[:, :3, :3] = rotation.as_matrix()  # orthonormal: near pi, logm is sensitive to float32 rounding
        twist = np.stack([scipy.linalg.logm(pose).real for pose in T])
        t, r = twist[:, :3, 3], twist[:, [2, 0, 1], [1, 2, 0]]  # rho; omega from hat(omega)
    elif cls is GeodesicLoss:
        r = rotation.as_rotvec()
    elif cls is SixDLoss:
        r = np.concatenate((R[:, :, 0], R[:, :, 1]), axis=-1)
    elif cls is SVDLoss:
        r = (R @ np.diag([1.0, 2.0, 3.0])).reshape(-1, 9)
    elif cls is SymMatrixQuatLoss:
        q = rotation.as_quat()
        A = np.eye(4) - q[:, :, None] * q[:, None, :]
        r = A[:, [0, 1, 2, 3, 1, 2, 3, 2, 3, 3], [0, 0, 0, 0, 1, 1, 1, 2, 2, 3]]
    else:
        raise AssertionError(f"no independent encoding for {cls.__name__}")
    out = torch.from_numpy(np.concatenate((t, r), axis=-1))
    return out.reshape(*target.shape[:-2], cls.dim).to(target.dtype)


def p(*values: float) -> torch.Tensor:
    """(1, 1, D) float64 prediction."""
    return torch.tensor(values, dtype=torch.float64)[None, None]


# -- parameterisation -------------------------------------------------------------------------------


def test_head_sizes_and_default_weights() -> None:
    # The default k is the matched weighting, 100 / small_angle_gain; paper_k the study's.
    assert [(c.dim, c().k) for c in LOSSES] == [
        (6, 100.0), (7, 400.0), (6, 50.0), (6, 100.0), (9, 50.0), (12, 50.0), (13, 50.0)
    ]  # fmt: skip
    assert [c.paper_k for c in LOSSES[:3]] == [100.0, 14.0, 153.0]


@pytest.mark.parametrize("cls", LOSSES)
def test_decode_encode_round_trip(cls: type[PoseLoss]) -> None:
    loss = cls()
    target = targets(dtype=torch.float64)  # rotations from 0 to 179.9 deg
    pred = independent_encoding(cls, target)
    torch.testing.assert_close(loss.decode(pred), target, atol=1e-12, rtol=0)
    torch.testing.assert_close(loss.decode(loss.encode(target)), target, atol=1e-12, rtol=0)
    if cls not in (SVDLoss, SymMatrixQuatLoss):  # the others' encodings are unique: encode gives them
        torch.testing.assert_close(loss.encode(target), pred, atol=1e-12, rtol=0)


@pytest.mark.parametrize("cls", LOSSES)
def test_zero_loss_at_the_target(cls: type[PoseLoss]) -> None:
    loss = cls()
    target = targets()
    out = loss(independent_encoding(cls, target), target)
    assert set(out) == KEYS
    for key, value in out.items():
        assert value.shape == ()
        assert value.item() == pytest.approx(0.0, abs=1e-6), key


# -- hand-computed examples -------------------------------------------------------------------------


def test_euler_hand_example() -> None:
    # pred: no motion; target: t = (1, 2, 2), yaw 0.5 rad. 9 + 100 * 0.25 = 34.
    out = EulerLoss()(p(0, 0, 0, 0, 0, 0), pose(rot(1, 0.5), (1.0, 2.0, 2.0)))
    assert out["trans_loss"].item() == pytest.approx(9.0)
    assert out["rot_loss"].item() == pytest.approx(0.25)
    assert out["loss"].item() == pytest.approx(34.0)
    assert out["trans_err_m"].item() == pytest.approx(3.0)
    assert out["rot_err_rad"].item() == pytest.approx(0.5)


def test_euler_targets_are_angles_of_the_relative_rotation() -> None:
    # Ry(0.2) Rx(0.1) Rz(-0.3) has Euler angles (0.2, 0.1, -0.3): a zero-loss prediction.
    R = rot(1, 0.2) @ rot(0, 0.1) @ rot(2, -0.3)
    assert EulerLoss()(p(0, 0, 0, 0.2, 0.1, -0.3), pose(R))["loss"].item() == pytest.approx(0.0, abs=1e-20)


def test_quaternion_hand_example() -> None:
    # pred identity (w = 1); target 90 deg about z: q = (cos 45, 0, 0, sin 45);
    # |q - q^|^2 = (1 - sqrt(2)/2)^2 + 1/2 = 2 - sqrt(2).
    out = QuaternionLoss(k=14.0)(p(0, 0, 0, 1, 0, 0, 0), pose(rot(2, math.pi / 2)))
    assert out["rot_loss"].item() == pytest.approx(2 - math.sqrt(2))
    assert out["loss"].item() == pytest.approx(14 * (2 - math.sqrt(2)))
    assert out["rot_err_rad"].item() == pytest.approx(math.pi / 2)


def test_chordal_hand_example() -> None:
    # xi = (rho = (1, 0, 0), omega = (0, 0, pi/2)): R = Rz(90 deg), t = V rho = (2/pi, 2/pi, 0).
    loss = ChordalLoss(k=153.0)
    xi = p(1, 0, 0, 0, 0, math.pi / 2)
    expected = pose(rot(2, math.pi / 2), (2 / math.pi, 2 / math.pi, 0.0))
    torch.testing.assert_close(loss.decode(xi), expected, atol=1e-15, rtol=0)
    # Against the identity: |t|^2 = 8 / pi^2 and |Rz(90) - I|_F^2 = 4.
    out = loss(xi, pose(torch.eye(3, dtype=torch.float64)))
    assert out["trans_loss"].item() == pytest.approx(8 / math.pi**2)
    assert out["rot_loss"].item() == pytest.approx(4.0)
    assert out["loss"].item() == pytest.approx(8 / math.pi**2 + 153 * 4)


def test_geodesic_hand_example() -> None:
    out = GeodesicLoss()(p(0, 0, 0, 0, 0.3, 0), pose(torch.eye(3, dtype=torch.float64)))
    assert out["rot_loss"].item() == pytest.approx(0.09)
    assert out["loss"].item() == pytest.approx(9.0)


def test_sixd_hand_example() -> None:
    # Columns (2, 0, 0) and (1, 3, 0) orthonormalise to the identity; target Rz(90): |I - Rz|_F^2 = 4.
    out = SixDLoss(k=153.0)(p(0, 0, 1, 2, 0, 0, 1, 3, 0), pose(rot(2, math.pi / 2)))
    assert out["trans_loss"].item() == pytest.approx(1.0)
    assert out["rot_loss"].item() == pytest.approx(4.0)
    assert out["loss"].item() == pytest.approx(1 + 153 * 4)


def test_loss_is_mean_over_pairs() -> None:
    gen = torch.Generator().manual_seed(3)
    for cls in LOSSES:
        loss = cls(k=7.0)
        pred = torch.randn(3, 4, cls.dim, generator=gen, dtype=torch.float64)
        target = targets(3, 4, dtype=torch.float64)
        per_pair = [loss(pred[b, t], target[b, t])["loss"] for b in range(3) for t in range(4)]
        assert loss(pred, target)["loss"].item() == pytest.approx(torch.stack(per_pair).mean().item())


# -- gradients and sign invariance ------------------------------------------------------------------


@pytest.mark.parametrize("cls", LOSSES)
def test_gradients_finite_at_identity_and_near_pi(cls: type[PoseLoss]) -> None:
    loss = cls()
    target = targets()  # contains an identity and a 179.9 deg target
    gen = torch.Generator().manual_seed(1)
    for pred in (torch.zeros(4, 5, cls.dim), loss.encode(target), torch.randn(4, 5, cls.dim, generator=gen)):
        pred = pred.clone().requires_grad_()
        loss(pred, target)["loss"].backward()
        assert torch.isfinite(pred.grad).all()


def test_quaternion_zero_output_has_finite_gradient() -> None:
    pred = torch.zeros(2, 3, 7, requires_grad=True)
    out = QuaternionLoss()(pred, targets(2, 3))
    out["loss"].backward()
    assert torch.isfinite(out["loss"]) and torch.isfinite(pred.grad).all()


def test_quaternion_sign_invariance() -> None:
    loss = QuaternionLoss()
    target = targets()
    pred = torch.randn(4, 5, 7, generator=torch.Generator().manual_seed(2))
    flipped = torch.cat((pred[..., :3], -pred[..., 3:]), dim=-1)
    a, b = loss(pred, target), loss(flipped, target)
    for key in KEYS:
        assert a[key].item() == b[key].item(), key


# -- dtypes and precision ---------------------------------------------------------------------------


@pytest.mark.parametrize("cls", LOSSES)
def test_bf16_autocast_does_not_reach_the_loss(cls: type[PoseLoss]) -> None:
    loss = cls()
    target = targets()
    pred = torch.randn(4, 5, cls.dim, generator=torch.Generator().manual_seed(4))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = loss(pred, target)
    assert out["loss"].dtype == torch.float32
    assert out["loss"].item() == loss(pred, target)["loss"].item()


def test_yardsticks_carry_no_gradient() -> None:
    pred = torch.randn(2, 3, 6, requires_grad=True)
    out = ChordalLoss()(pred, targets(2, 3))
    assert not out["trans_err_m"].requires_grad and not out["rot_err_rad"].requires_grad


# -- bad input --------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", LOSSES)
def test_non_finite_predictions_give_non_finite_losses(cls: type[PoseLoss]) -> None:
    for bad in (float("nan"), float("inf")):
        for column in range(cls.dim):  # in the translation and in every rotation output
            pred = torch.zeros(2, 3, cls.dim)
            pred[1, 2, column] = bad
            assert not torch.isfinite(cls()(pred, targets(2, 3))["loss"]), (bad, column)


@pytest.mark.parametrize("cls", LOSSES)
def test_wrong_shapes_raise_value_errors(cls: type[PoseLoss]) -> None:
    loss, target = cls(), targets(2, 3)
    with pytest.raises(
        ValueError, match=rf"expects pred of shape \(\.\.\., {cls.dim}\), got \(2, 3, {cls.dim + 1}\)"
    ):
        loss(torch.zeros(2, 3, cls.dim + 1), target)
    with pytest.raises(ValueError, match=r"expects target of shape \(\.\.\., 4, 4\), got \(2, 3, 3, 4\)"):
        loss(torch.zeros(2, 3, cls.dim), target[..., :3, :])
    with pytest.raises(ValueError, match=r"expected target of shape \(2, 4, 4, 4\)"):
        loss(torch.zeros(2, 4, cls.dim), target)
    with pytest.raises(ValueError, match=rf"expects pred of shape \(\.\.\., {cls.dim}\)"):
        loss.decode(torch.zeros(5, cls.dim + 2))


@pytest.mark.parametrize("k", [-1.0, float("nan"), float("inf"), "100", True])
def test_invalid_weight_is_rejected(k: object) -> None:
    with pytest.raises(UserError, match=r"loss\.k: expected a finite number >= 0 for EulerLoss"):
        EulerLoss(k=k)


# -- Hydra ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "cls", "matched_k"),
    [
        ("euler", EulerLoss, 100.0),
        ("quat", QuaternionLoss, 400.0),
        ("chordal", ChordalLoss, 50.0),
        ("geodesic", GeodesicLoss, 100.0),
        ("sixd", SixDLoss, 50.0),
        ("svd", SVDLoss, 50.0),
        ("quat10d", SymMatrixQuatLoss, 50.0),
    ],
)
def test_hydra_loss_group(name: str, cls: type[PoseLoss], matched_k: float) -> None:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        default = instantiate(compose("train", overrides=[f"loss={name}"]).loss)
        tuned = instantiate(compose("train", overrides=[f"loss={name}", "loss.k=50"]).loss)
    assert type(default) is cls and default.k == matched_k  # weighting=matched: 100 / small_angle_gain
    assert type(tuned) is cls and tuned.k == 50.0


# -- 9-D and 10-D parameterisations at degenerate outputs -------------------------------------------


@pytest.mark.parametrize(
    ("cls", "rotation_part"),
    [
        (SVDLoss, torch.zeros(9)),  # M = 0: every singular value 0
        (SVDLoss, torch.tensor([1.0, 2, 3, 2, 4, 6, 3, 6, 9])),  # rank 1
        (SVDLoss, torch.tensor([1.0, 0, 0, 0, 1, 0, 0, 0, -1])),  # det < 0 with equal singular values
        (SymMatrixQuatLoss, torch.zeros(10)),  # A = 0: the smallest eigenvalue four times
        (SymMatrixQuatLoss, torch.tensor([1.0, 0, 0, 0, 1, 0, 0, 1, 0, 1])),  # A = I
        (SymMatrixQuatLoss, torch.tensor([0.0, 0, 0, 0, 0, 0, 0, 1, 0, 1])),  # smallest eigenvalue twice
    ],
)
def test_degenerate_outputs_give_finite_values_and_gradients(cls: type[PoseLoss], rotation_part) -> None:
    loss = cls()
    pred = torch.cat((torch.tensor([0.1, 0.0, 1.0]), rotation_part)).double()[None, None].requires_grad_()
    out = loss(pred, targets(1, 2, dtype=torch.float64)[:, 1:])
    R = loss.decode(pred)[..., :3, :3]
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand_as(R))
    assert torch.isfinite(out["loss"])
    out["loss"].backward()
    assert torch.isfinite(pred.grad).all()


def test_svd_projection_is_the_nearest_rotation() -> None:
    gen = torch.Generator().manual_seed(5)
    M = torch.randn(64, 3, 3, generator=gen, dtype=torch.float64)
    R = SVDLoss().decode(torch.cat((torch.zeros(64, 3, dtype=torch.float64), M.flatten(-2)), -1))[:, :3, :3]
    U, _, Vh = torch.linalg.svd(M)
    D = torch.diag_embed(torch.stack([torch.ones(64), torch.ones(64), torch.det(U @ Vh)], -1).double())
    torch.testing.assert_close(R, U @ D @ Vh)  # special Procrustes, computed independently


def test_symmetric_matrix_quaternion_is_the_smallest_eigenvector() -> None:
    gen = torch.Generator().manual_seed(6)
    x = torch.randn(64, 10, generator=gen, dtype=torch.float64)
    R = SymMatrixQuatLoss().decode(torch.cat((torch.zeros(64, 3, dtype=torch.float64), x), -1))[:, :3, :3]
    A = torch.zeros(64, 4, 4, dtype=torch.float64)
    entries = [(0, 0), (1, 0), (2, 0), (3, 0), (1, 1), (2, 1), (3, 1), (2, 2), (3, 2), (3, 3)]  # roma's order
    for j, (r, c) in enumerate(entries):
        A[:, r, c] = A[:, c, r] = x[:, j]
    q_xyzw = torch.linalg.eigh(A)[1][..., 0]
    torch.testing.assert_close(R, torch.from_numpy(Rotation.from_quat(q_xyzw.numpy()).as_matrix()))
