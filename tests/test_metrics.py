"""lossvo.metrics against evo itself and against a loop-based KITTI devkit reference."""

from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PosePath3D
from evo.tools import file_interface

from helpers import DEVICES
from lossvo import geometry
from lossvo import metrics as metrics_cli
from lossvo.console import UserError
from lossvo.data.kitti import read_poses
from lossvo.evaluation import metrics

MODES = ("none", "se3", "sim3", "scale")


# --------------------------------------------------------------------------------------------------
# Generated trajectories
# --------------------------------------------------------------------------------------------------


def make_reference(n: int, seed: int = 0, speed: float = 1.2) -> torch.Tensor:
    """A car-like path with turns: (n, 4, 4) float64 poses, ~speed metres per frame along camera z."""
    g = torch.Generator().manual_seed(seed)
    k = torch.arange(n, dtype=torch.float64)
    yaw = 1.5 * torch.sin(k / 97.0) + 0.8 * torch.sin(k / 23.0 + 1.0) + 0.01 * torch.randn(n, generator=g)
    pitch = 0.03 * torch.sin(k / 41.0)
    roll = 0.02 * torch.cos(k / 37.0)
    R = geometry.euler_to_matrix(torch.stack((yaw, pitch, roll), dim=-1))
    step = speed * (1.0 + 0.2 * torch.sin(k / 61.0))
    t = torch.cumsum(R[:, :, 2] * step[:, None], dim=0)
    return geometry.make_pose(R, t - t[0])


def make_estimate(ref: torch.Tensor, seed: int = 1, scale: float = 1.0) -> torch.Tensor:
    """A noisy, drifting, scaled and globally moved copy of ``ref`` (so that every alignment matters)."""
    g = torch.Generator().manual_seed(seed)
    n = len(ref)
    rot_noise = geometry.so3_exp(0.01 * torch.randn(n, 3, generator=g, dtype=torch.float64))
    drift = torch.cumsum(0.02 * torch.randn(n, 3, generator=g, dtype=torch.float64), dim=0)
    R = ref[:, :3, :3] @ rot_noise
    t = scale * ref[:, :3, 3] + drift + 0.05 * torch.randn(n, 3, generator=g, dtype=torch.float64)
    est = geometry.make_pose(R, t)
    world = geometry.make_pose(
        geometry.so3_exp(torch.tensor([0.1, -0.3, 0.2], dtype=torch.float64)),
        torch.tensor([3.0, -1.0, 2.0], dtype=torch.float64),
    )
    return world @ est


def write_kitti(path: Path, poses: torch.Tensor) -> Path:
    """Write poses with 7 significant digits, like real KITTI files (rotations slightly non-orthonormal)."""
    np.savetxt(path, poses[:, :3, :].reshape(-1, 12).numpy(), fmt="%.6e")
    return path


def read_both(path: Path) -> tuple[torch.Tensor, PosePath3D]:
    """The file as lossvo reads it and as evo reads it."""
    from lossvo.data.kitti import read_poses

    return torch.from_numpy(read_poses(path)), file_interface.read_kitti_poses_file(str(path))


@pytest.fixture(scope="module")
def cases(tmp_path_factory) -> list[tuple[str, torch.Tensor, torch.Tensor, PosePath3D, PosePath3D]]:
    """(name, est, ref, evo est, evo ref): exact float64 trajectories and the same written to files."""
    tmp = tmp_path_factory.mktemp("traj")
    out = []
    for name, n, seed, scale in (("long", 1000, 0, 1.0), ("scaled", 600, 3, 0.7), ("short", 50, 5, 1.3)):
        ref = make_reference(n, seed)
        est = make_estimate(ref, seed + 1, scale)
        out.append(
            (name, est, ref, PosePath3D(poses_se3=list(est.numpy())), PosePath3D(poses_se3=list(ref.numpy())))
        )
        est_f, evo_est = read_both(write_kitti(tmp / f"{name}_est.txt", est))
        ref_f, evo_ref = read_both(write_kitti(tmp / f"{name}_ref.txt", ref))
        out.append((name + "-7digits", est_f, ref_f, evo_est, evo_ref))
    return out


def evo_stats(metric) -> dict[str, float]:
    stats = metric.get_all_statistics()
    return {k: stats[k] for k in metrics.STATISTICS}


def evo_ape(evo_est: PosePath3D, evo_ref: PosePath3D, mode: str) -> dict[str, dict[str, float]]:
    import copy

    est = copy.deepcopy(evo_est)
    if mode != "none":
        est.align(evo_ref, correct_scale=mode == "sim3", correct_only_scale=mode == "scale")
    out = {}
    for key, relation in (
        ("trans", evo_metrics.PoseRelation.translation_part),
        ("rot_rad", evo_metrics.PoseRelation.rotation_angle_rad),
    ):
        ape = evo_metrics.APE(relation)
        ape.process_data((evo_ref, est))
        out[key] = evo_stats(ape)
    return out


def evo_rpe(
    evo_est: PosePath3D, evo_ref: PosePath3D, delta: float, mode: str = "none", unit: str = "f",
    from_reference: bool = False,
) -> dict[str, dict[str, float]]:  # fmt: skip
    if mode != "none":  # as evo_rpe --align / --correct_scale
        evo_est = copy.deepcopy(evo_est)
        evo_est.align(evo_ref, correct_scale=mode == "sim3", correct_only_scale=mode == "scale")
    out = {}
    for key, relation in (
        ("trans", evo_metrics.PoseRelation.translation_part),
        ("rot_rad", evo_metrics.PoseRelation.rotation_angle_rad),
    ):
        delta_unit = evo_metrics.Unit.frames if unit == "f" else evo_metrics.Unit.meters
        rpe = evo_metrics.RPE(relation, delta=delta, delta_unit=delta_unit, all_pairs=False,
                              pairs_from_reference=from_reference)  # fmt: skip
        rpe.process_data((evo_ref, evo_est))
        out[key] = evo_stats(rpe)
    return out


def assert_stats_close(ours: dict, theirs: dict, rot_rtol: float, where: str) -> None:
    for key, rtol in (("trans", 1e-9), ("rot_rad", rot_rtol)):
        for name in metrics.STATISTICS:
            a, b = ours[key][name], theirs[key][name]
            assert a == pytest.approx(b, rel=rtol, abs=1e-12), f"{where} {key} {name}: {a} vs evo {b}"


# --------------------------------------------------------------------------------------------------
# APE / RPE equal to evo's
# --------------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
def test_ape_equals_evo(cases, mode):
    for name, est, ref, evo_est, evo_ref in cases:
        trans, rot = metrics.ape_errors(est, ref, align=mode)
        ours = {"trans": metrics.statistics(trans), "rot_rad": metrics.statistics(rot)}
        rot_rtol = 1e-6 if name.endswith("7digits") else 1e-9
        assert_stats_close(ours, evo_ape(evo_est, evo_ref, mode), rot_rtol, f"{name} align={mode}")


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
def test_rpe_after_alignment_equals_evo_rpe_with_align_and_correct_scale(cases, mode):
    for name, est, ref, evo_est, evo_ref in cases:
        trans, rot = metrics.rpe_errors(est, ref, delta=3, align=mode)
        ours = {"trans": metrics.statistics(trans), "rot_rad": metrics.statistics(rot)}
        rot_rtol = 1e-6 if name.endswith("7digits") else 1e-9
        assert_stats_close(ours, evo_rpe(evo_est, evo_ref, 3, mode), rot_rtol, f"{name} align={mode}")
    if any(mode == m for m in ("sim3", "scale")):  # the scale changes relative translations
        _, est, ref, _, _ = cases[0]
        assert not torch.allclose(
            metrics.rpe_errors(est, ref, 3, mode)[0], metrics.rpe_errors(est, ref, 3)[0]
        )


@pytest.mark.parametrize("pairs_from", ["estimate", "reference"])
@pytest.mark.parametrize("mode", ["none", "sim3"])
def test_rpe_in_metres_equals_evo_with_pairs_from_either_path(cases, pairs_from, mode):
    for name, est, ref, evo_est, evo_ref in cases:
        delta = 0.15 * float(metrics.trajectory_distances(ref)[-1])  # about 6 pairs
        trans, rot = metrics.rpe_errors(est, ref, delta, mode, delta_unit="m", pairs_from=pairs_from)
        ours = {"trans": metrics.statistics(trans), "rot_rad": metrics.statistics(rot)}
        rot_rtol = 1e-6 if name.endswith("7digits") else 1e-9
        theirs = evo_rpe(evo_est, evo_ref, delta, mode, "m", pairs_from == "reference")
        assert_stats_close(ours, theirs, rot_rtol, f"{name} {delta:.3g} m from {pairs_from}, align={mode}")
    _, est, ref, _, _ = cases[0]
    delta = 0.15 * float(metrics.trajectory_distances(ref)[-1])
    by_est, by_ref = (metrics.rpe_pairs_by_path(p, delta) for p in (est, ref))
    assert len(by_est[0]) >= 3 and not (
        len(by_est[0]) == len(by_ref[0]) and torch.equal(by_est[0], by_ref[0])
    ), "the two paths should pick different pairs on this case, or the test shows nothing"


@pytest.mark.parametrize(("delta", "unit", "pairs_from", "message"), [
    (0, "m", "estimate", "positive path distance"), (1.5, "f", "estimate", "positive integer"),
    (1, "s", "estimate", "delta_unit"), (1, "f", "both", "pairs_from"),
])  # fmt: skip
def test_rpe_settings_are_checked(delta, unit, pairs_from, message):
    with pytest.raises(UserError, match=message):
        metrics.RPE(delta=delta, delta_unit=unit, pairs_from=pairs_from)


@pytest.mark.slow
@pytest.mark.parametrize("delta", [1, 7])
def test_rpe_equals_evo(cases, delta):
    for name, est, ref, evo_est, evo_ref in cases:
        trans, rot = metrics.rpe_errors(est, ref, delta=delta)
        assert len(trans) == (len(est) - 1) // delta
        ours = {"trans": metrics.statistics(trans), "rot_rad": metrics.statistics(rot)}
        rot_rtol = 1e-6 if name.endswith("7digits") else 1e-9
        assert_stats_close(ours, evo_rpe(evo_est, evo_ref, delta), rot_rtol, f"{name} delta={delta}")


@pytest.mark.parametrize("mode", ["se3", "sim3", "scale"])
def test_align_equals_evo_poses(mode):
    import copy

    ref = make_reference(300, 11)
    est = make_estimate(ref, 12, 0.8)
    evo_est = PosePath3D(poses_se3=list(est.numpy()))
    evo_est_aligned = copy.deepcopy(evo_est)
    evo_est_aligned.align(PosePath3D(poses_se3=list(ref.numpy())), mode == "sim3", mode == "scale")
    ours = metrics.align(est, ref, mode).numpy()
    np.testing.assert_allclose(ours, np.stack(evo_est_aligned.poses_se3), rtol=1e-9, atol=1e-9)


def test_statistics_like_numpy():
    e = torch.tensor([3.0, 1.0, 4.0, 1.5])
    s = metrics.statistics(e)
    x = e.double().numpy()
    assert s["median"] == pytest.approx(np.median(x))  # mean of the middle two
    assert s["std"] == pytest.approx(np.std(x))  # ddof 0
    assert s["rmse"] == pytest.approx(math.sqrt(np.mean(x**2)))
    assert (s["min"], s["max"], s["mean"]) == (1.0, 4.0, pytest.approx(2.375))
    with pytest.raises(UserError, match="no errors"):
        metrics.statistics(torch.zeros(0))


def test_identical_trajectories_have_zero_error():
    ref = make_reference(200)
    for mode in MODES:
        trans, rot = metrics.ape_errors(ref, ref, align=mode)
        assert float(trans.max()) < 1e-9 and float(rot.max()) < 1e-9


@pytest.mark.parametrize("device", DEVICES)
def test_any_device_same_numbers(device):
    ref = make_reference(1200, 7)
    est = make_estimate(ref, 8)
    for fn in (
        lambda e, r: metrics.ape_errors(e, r, "sim3"),
        lambda e, r: metrics.rpe_errors(e, r, 2),
        metrics.kitti_segment_errors,
    ):
        expected = fn(est, ref)
        got = fn(est.to(device), ref.to(device))
        for a, b in zip(got, expected, strict=True):
            assert a.device.type == device and a.dtype == torch.float64
            torch.testing.assert_close(a.cpu(), b, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------------------


def test_bad_input():
    ref = make_reference(20)
    est = make_estimate(ref)
    with pytest.raises(UserError, match="differ in length"):
        metrics.ape_errors(est[:-1], ref)
    with pytest.raises(UserError, match="differ in length"):
        metrics.rpe_errors(est, ref[:-1])
    with pytest.raises(UserError, match="at least 2 poses"):
        metrics.ape_errors(est[:1], ref[:1])
    with pytest.raises(UserError, match="at least 3 poses"):
        metrics.ape_errors(est[:2], ref[:2], align="se3")
    with pytest.raises(UserError, match="needs more than 5 poses"):
        metrics.rpe_errors(est[:5], ref[:5], delta=5)
    with pytest.raises(UserError, match="delta"):
        metrics.rpe_errors(est, ref, delta=0)
    with pytest.raises(UserError, match="unknown alignment"):
        metrics.align(est, ref, "sim2")
    with pytest.raises(UserError, match=r"shape \(N, 4, 4\)"):
        metrics.ape_errors(est[:, :3], ref[:, :3])


def test_nan_pose_names_first_bad_index():
    ref = make_reference(20)
    est = make_estimate(ref).clone()
    est[7, 0, 3] = float("nan")
    est[9, 1, 1] = float("inf")
    for call in (
        lambda: metrics.ape_errors(est, ref),
        lambda: metrics.rpe_errors(est, ref),
        lambda: metrics.align(est, ref, "se3"),
    ):
        with pytest.raises(UserError, match="est pose 7 is not finite"):
            call()
    with pytest.raises(UserError, match="ref pose 7 is not finite"):
        metrics.kitti_segment_errors(ref, est)


@pytest.mark.parametrize("mode", ["se3", "sim3", "scale"])
def test_degenerate_alignment(mode):
    ref = make_reference(10)
    est = ref.clone()
    est[:, :3, 3] = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    with pytest.raises(UserError, match="degenerate alignment: all positions identical"):
        metrics.align(est, ref, mode)
    with pytest.raises(UserError, match="degenerate alignment"):
        metrics.ape_errors(ref, est, align=mode)


# --------------------------------------------------------------------------------------------------
# KITTI odometry error against the devkit's loops
# --------------------------------------------------------------------------------------------------


def kitti_devkit(gt: np.ndarray, est: np.ndarray, lengths=metrics.KITTI_LENGTHS, step=10):
    """Transcription of the devkit's calcSequenceErrors (evaluate_odometry.cpp) in float64: segment lists."""
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[i - 1] + float(np.linalg.norm(gt[i - 1, :3, 3] - gt[i, :3, 3])))
    t_errs, r_errs = [], []
    for first in range(0, len(gt), step):
        for length in lengths:
            last = next((i for i in range(first, len(dist)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            delta_gt = np.linalg.inv(gt[first]) @ gt[last]
            delta_est = np.linalg.inv(est[first]) @ est[last]
            err = np.linalg.inv(delta_est) @ delta_gt
            d = 0.5 * (np.trace(err[:3, :3]) - 1.0)
            r_errs.append(math.acos(max(min(d, 1.0), -1.0)) / length)
            t_errs.append(float(np.linalg.norm(err[:3, 3])) / length)
    return t_errs, r_errs


def test_kitti_equals_devkit_loops():
    ref = make_reference(1000, 0)
    est = make_estimate(ref, 1)
    t_ref, r_ref = kitti_devkit(ref.numpy(), est.numpy())
    t, r = metrics.kitti_segment_errors(est, ref)
    assert len(t_ref) > 100
    np.testing.assert_allclose(t.numpy(), t_ref, rtol=1e-9)
    np.testing.assert_allclose(r.numpy(), r_ref, rtol=1e-9, atol=1e-15)
    kitti = metrics.evaluate(ref, est)["kitti"]
    t_pct, r_deg = kitti["t_err_pct"], kitti["r_err_deg_per_100m"]
    assert t_pct == pytest.approx(100 * np.mean(t_ref), rel=1e-9)
    assert r_deg == pytest.approx(100 * math.degrees(np.mean(r_ref)), rel=1e-9)


def test_kitti_equals_devkit_loops_on_7_digit_files_that_are_not_orthonormal(tmp_path):
    """Pose files written with 7 significant digits (as ORB-SLAM's), read back: rotations are then not
    exactly orthonormal, and the devkit's arccos formula is what defines the error."""
    ref = make_reference(1000, 0)
    est = make_estimate(ref, 1)
    for name, poses in (("gt.txt", ref), ("est.txt", est)):
        np.savetxt(tmp_path / name, poses[:, :3].reshape(len(poses), 12).numpy(), fmt="%.6e")
    ref7 = torch.from_numpy(read_poses(tmp_path / "gt.txt"))
    est7 = torch.from_numpy(read_poses(tmp_path / "est.txt"))
    R = est7[:, :3, :3]
    assert (R @ R.transpose(-1, -2) - torch.eye(3, dtype=R.dtype)).abs().max() > 1e-8  # not orthonormal
    t_ref, r_ref = kitti_devkit(ref7.numpy(), est7.numpy())
    t, r = metrics.kitti_segment_errors(est7, ref7)
    np.testing.assert_allclose(t.numpy(), t_ref, rtol=1e-9)
    np.testing.assert_allclose(r.numpy(), r_ref, rtol=1e-9, atol=1e-15)
    kitti = metrics.evaluate(ref7, est7)["kitti"]
    t_pct, r_deg = kitti["t_err_pct"], kitti["r_err_deg_per_100m"]
    assert t_pct == pytest.approx(100 * np.mean(t_ref), rel=1e-9)
    assert r_deg == pytest.approx(100 * math.degrees(np.mean(r_ref)), rel=1e-9)


def test_kitti_short_sequence_is_none():
    ref = make_reference(50)  # about 60 m: shorter than the shortest segment
    est = make_estimate(ref)
    assert metrics.evaluate(ref, est)["kitti"] == {"t_err_pct": None, "r_err_deg_per_100m": None}
    t, r = metrics.kitti_segment_errors(est, ref)
    assert t.numel() == r.numel() == 0
    metric = metrics.KittiOdometryError()
    metric.update(est, ref)
    assert metric.compute() == {"t_err_pct": None, "r_err_deg_per_100m": None}


# --------------------------------------------------------------------------------------------------
# torchmetrics: pooling over sequences and reduction across processes
# --------------------------------------------------------------------------------------------------


def _sequences() -> list[tuple[torch.Tensor, torch.Tensor]]:
    seqs = []
    for seed, n in ((0, 400), (2, 250), (4, 30), (6, 500)):
        ref = make_reference(n, seed)
        seqs.append((make_estimate(ref, seed + 1), ref))
    return seqs


@pytest.mark.parametrize(
    "factory", [lambda: metrics.APE("sim3"), lambda: metrics.RPE(3), metrics.KittiOdometryError]
)
def test_metric_pools_and_merges(factory):
    seqs = _sequences()
    whole, first, second = factory(), factory(), factory()
    for est, ref in seqs:
        whole.update(est, ref)
    for est, ref in seqs[:2]:
        first.update(est, ref)
    for est, ref in seqs[2:]:
        second.update(est, ref)
    expected = whole.compute()
    first.merge_state(second)  # the two shards, as a cross-process reduction combines them
    merged = first.compute()
    assert json.dumps(merged, sort_keys=True) == json.dumps(expected, sort_keys=True) or _close(
        merged, expected
    )


def _close(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    return a == pytest.approx(b, rel=1e-12)


def test_metric_statistics_are_pooled_errors():
    seqs = _sequences()
    ape = metrics.APE("se3")
    for est, ref in seqs:
        ape.update(est, ref)
    errors = [metrics.ape_errors(est, ref, "se3") for est, ref in seqs]
    result = ape.compute()
    assert result["trans"] == metrics.statistics(torch.cat([t for t, _ in errors]))
    assert result["rot_rad"] == metrics.statistics(torch.cat([r for _, r in errors]))
    kitti = metrics.KittiOdometryError()
    for est, ref in seqs:
        kitti.update(est, ref)
    segs = [metrics.kitti_segment_errors(est, ref) for est, ref in seqs]
    t_all = torch.cat([t for t, _ in segs])
    assert kitti.compute()["t_err_pct"] == pytest.approx(100 * float(t_all.mean()), rel=1e-12)


# --------------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cli_files(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(ground truth, estimate, an estimate whose line 4 is malformed) pose files."""
    tmp = tmp_path_factory.mktemp("cli")
    ref = make_reference(300)
    gt_file = write_kitti(tmp / "gt.txt", ref)
    est_file = write_kitti(tmp / "est.txt", make_estimate(ref))
    lines = est_file.read_text().splitlines()
    lines[3] = "1 2 3"
    bad = tmp / "bad.txt"
    bad.write_text("\n".join(lines) + "\n")
    return gt_file, est_file, bad


def test_cli_json(cli_files, capsys):
    gt_file, est_file, _ = cli_files
    assert metrics_cli.main([str(gt_file), str(est_file), "--align", "se3", "--delta", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) == {"ape", "rpe", "kitti"}
    for key in ("ape", "rpe"):
        assert set(result[key]) == {"trans", "rot_rad"}
        assert set(result[key]["trans"]) == set(metrics.STATISTICS)
    assert set(result["kitti"]) == {"t_err_pct", "r_err_deg_per_100m"}
    assert result["kitti"]["t_err_pct"] > 0


def test_cli_survives_a_closed_pipe(cli_files, monkeypatch):
    """``lossvo.metrics --json`` whose reader closes its end at once (as ``| head`` does when done): no
    BrokenPipeError. In process, with stdout a real pipe whose read end is closed."""
    gt_file, est_file, _ = cli_files
    read_end, write_end = os.pipe()
    os.close(read_end)
    with os.fdopen(write_end, "w") as pipe:
        monkeypatch.setattr(sys, "stdout", pipe)
        assert metrics_cli.main([str(gt_file), str(est_file), "--json"]) == 0
        monkeypatch.undo()


def test_output_into_a_closed_pipe_ends_the_interpreter_cleanly():
    """A real interpreter printing through ``console.emit`` into a closed pipe exits 0 with nothing on
    stderr: its final flush of stdout succeeds too."""
    code = "from lossvo.console import emit; emit('x' * 1_000_000); emit('more')"
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == 0 and err == ""


def test_cli_malformed_file(cli_files, capsys):
    gt_file, _, bad = cli_files
    assert metrics_cli.main([str(gt_file), str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{bad}:4" in err


def test_cli_table_and_short_sequence(tmp_path, capsys):
    """In-process (a subprocess costs seconds of imports): the table, and null KITTI values when too short."""
    ref = make_reference(30)
    gt_file = write_kitti(tmp_path / "gt.txt", ref)
    est_file = write_kitti(tmp_path / "est.txt", make_estimate(ref))
    assert metrics_cli.main([str(gt_file), str(est_file)]) == 0
    table = capsys.readouterr().out
    assert "APE trans" in table and "RPE rot" in table and "too short" in table
    assert metrics_cli.main([str(gt_file), str(est_file), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["kitti"] == {"t_err_pct": None, "r_err_deg_per_100m": None}
    assert metrics_cli.main([str(gt_file), str(tmp_path / "missing.txt")]) == 2
    assert "missing.txt" in capsys.readouterr().err
