"""The flow baseline (flow yaw + road speed, one line each on DIS flow): the yaw of a rendered pure yaw,
the road feature of rendered forward steps, the speed fit on numbers with a known constant, the relative
poses in lossvo's convention, and the baseline beside the others on a tiny rendered dataset: in NAMES,
finite, cached with the training split's flow (a second call computes no flow)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lossvo.data import flow
from lossvo.evaluation import baselines
from test_baselines import data_record, step
from test_flow import _counted, _frames, _rotation_flow, _yaw


def _forward(metres: float) -> np.ndarray:
    """4x4 step of ``metres`` along the camera's z axis (forward)."""
    T = np.eye(4)
    T[2, 3] = metres
    return T


@pytest.mark.parametrize("angle", [0.03, -0.03])
def test_the_flow_yaw_of_a_rendered_pure_yaw_has_its_sign_and_size(angle: float) -> None:
    """On DIS flow, the yaw reads what the one-line formula reads on the rotation's exact flow (its sign:
    turning right, the world moves left), 1.1-1.25x the true yaw (the median pixel lies off centre)."""
    frames, K = _frames(np.stack((np.eye(4), _yaw(angle))))
    fields = flow.pair_flow(frames[0], frames[1], baselines.FLOW_SETTING)[None]
    yaw = baselines.flow_yaw(fields, K)
    ideal = baselines.flow_yaw(_rotation_flow(K, _yaw(angle)[:3, :3])[None], K)
    assert yaw.shape == (1,) and yaw.dtype == np.float64
    assert 1.1 < ideal[0] / angle < 1.25
    assert yaw[0] == pytest.approx(ideal[0], rel=0.05)
    assert abs(baselines.road_speed_feature(fields)[0]) < 0.1  # a turn on the spot: no speed


def test_the_road_feature_grows_with_the_step_ahead() -> None:
    """Rendered steps straight ahead: the road moves down the image, about twice as far for twice the
    step; the yaw stays near zero."""
    frames, K = _frames(np.stack((np.eye(4), _forward(0.3), np.eye(4), _forward(0.6))))
    fields = np.stack([flow.pair_flow(frames[0], frames[1]), flow.pair_flow(frames[2], frames[3])])
    road = baselines.road_speed_feature(fields)
    assert road.shape == (2,) and road[0] > 0.5
    assert 1.8 < road[1] / road[0] < 2.2
    assert np.abs(baselines.flow_yaw(fields, K)).max() < 0.003


def test_the_speed_fit_recovers_a_known_constant() -> None:
    rng = np.random.default_rng(0)
    features = rng.uniform(0.0, 8.0, 500)
    assert baselines.fit_speed_scale(features, 0.21 * features) == pytest.approx(0.21, rel=1e-12)
    noisy = 0.21 * features + rng.normal(0.0, 0.05, 500)
    assert baselines.fit_speed_scale(features, noisy) == pytest.approx(0.21, abs=2e-3)
    offset = 0.21 * features + 0.5  # no intercept: the one constant absorbs an offset, as least squares does
    expected = (features @ offset) / (features @ features)
    assert baselines.fit_speed_scale(features, offset) == pytest.approx(expected) and expected > 0.25
    assert baselines.fit_speed_scale(np.zeros(3), np.ones(3)) == 0.0


def test_the_flow_motion_is_ry_of_the_yaw_and_the_speed_straight_ahead() -> None:
    yaw, speed = np.array([0.02, -0.05, 0.0]), np.array([0.8, 0.1, 0.0])
    np.testing.assert_allclose(
        baselines.flow_motion(yaw, speed), np.stack([step(y, s) for y, s in zip(yaw, speed, strict=True)]),
        atol=1e-15,
    )  # fmt: skip


def test_the_flow_baseline_is_listed_finite_and_cached_with_the_training_flow(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On the tiny rendered dataset (10 frames a sequence): the first call computes the flow of the two
    training sequences and the evaluated one, the second nothing, and a training sequence evaluated
    later reuses its features."""
    assert baselines.FLOW in baselines.NAMES
    data = data_record(tiny_kitti, tiny_kitti, ("00", "01"), test=("02",))
    calls = _counted(monkeypatch)
    first = baselines.compute_baselines(data, ["02"], tmp_path)["02"]
    assert len(calls) == 3 * 9 and tuple(first) == baselines.NAMES
    result = first[baselines.FLOW]
    assert result.trajectory.shape == (10, 4, 4) and np.isfinite(result.trajectory).all()
    errors = [getattr(getattr(result.scores, kind), relation).rmse
              for kind in ("ape", "rpe") for relation in ("trans", "rot_rad")]  # fmt: skip
    assert np.isfinite(errors).all() and min(errors) > 0 and not result.cached

    again = baselines.compute_baselines(data, ["02"], tmp_path)["02"]
    assert len(calls) == 3 * 9 and all(r.cached for r in again.values())
    np.testing.assert_array_equal(again[baselines.FLOW].trajectory, result.trajectory)
    baselines.compute_baselines(data, ["00"], tmp_path)  # a training sequence: its features are cached
    assert len(calls) == 3 * 9
