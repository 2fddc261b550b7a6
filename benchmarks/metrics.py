"""lossvo's APE + RPE against evo's on generated trajectories: seconds of each and the speed-up.

Per trajectory length N (4,541 = KITTI 00; 45,410 = ten times that), both libraries compute APE (translation
and rotation angle) without alignment and with SE(3) alignment, and RPE (delta = 1 frame, translation and
rotation angle), and take the six statistics of each. Target: lossvo >= 20x faster.

Run: ``python benchmarks/metrics.py [--sizes 4541 45410] [--repeats 3]`` (under two minutes on a laptop CPU).
"""

from __future__ import annotations

import argparse
import copy
import time
from collections.abc import Callable

import torch
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PosePath3D

from lossvo import geometry
from lossvo.evaluation import metrics

RELATIONS = (evo_metrics.PoseRelation.translation_part, evo_metrics.PoseRelation.rotation_angle_rad)


def make_pair(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """A turning reference path and a noisy, drifting estimate: two (n, 4, 4) float64 tensors."""
    g = torch.Generator().manual_seed(seed)
    k = torch.arange(n, dtype=torch.float64)
    angles = torch.stack(
        (1.5 * torch.sin(k / 97.0), 0.03 * torch.sin(k / 41.0), 0.02 * torch.cos(k / 37.0)), -1
    )
    R = geometry.euler_to_matrix(angles)
    ref = geometry.make_pose(R, torch.cumsum(R[:, :, 2], dim=0))
    noise_R = geometry.so3_exp(0.01 * torch.randn(n, 3, generator=g, dtype=torch.float64))
    drift = torch.cumsum(0.02 * torch.randn(n, 3, generator=g, dtype=torch.float64), dim=0)
    est = geometry.make_pose(R @ noise_R, ref[:, :3, 3] + drift)
    return est, ref


def lossvo_all(est: torch.Tensor, ref: torch.Tensor) -> list[dict]:
    """lossvo: APE (none, se3) and RPE, translation and rotation statistics."""
    out = []
    for mode in ("none", "se3"):
        out += [metrics.statistics(e) for e in metrics.ape_errors(est, ref, mode)]
    out += [metrics.statistics(e) for e in metrics.rpe_errors(est, ref, 1)]
    return out


def evo_all(est: PosePath3D, ref: PosePath3D) -> list[dict]:
    """evo: the same computations (the estimate is copied before its in-place alignment)."""
    out = []
    for mode in ("none", "se3"):
        path = copy.deepcopy(est)
        if mode == "se3":
            path.align(ref)
        for relation in RELATIONS:
            ape = evo_metrics.APE(relation)
            ape.process_data((ref, path))
            out.append(ape.get_all_statistics())
    for relation in RELATIONS:
        rpe = evo_metrics.RPE(relation, delta=1, delta_unit=evo_metrics.Unit.frames)
        rpe.process_data((ref, est))
        out.append(rpe.get_all_statistics())
    return out


def best_time(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """Best wall time (s) over ``repeats`` calls, and the last result."""
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4541, 45410])
    parser.add_argument("--repeats", type=int, default=3, help="lossvo repeats (evo runs once per size)")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, float64 on CPU")
    print(
        f"{'N':>8} {'lossvo s':>10} {'evo s':>10} {'speed-up':>10} {'max rel diff':>13} {'max abs diff':>13}"
    )
    for n in args.sizes:
        est, ref = make_pair(n)
        ours_t, ours = best_time(lambda est=est, ref=ref: lossvo_all(est, ref), args.repeats)
        evo_est, evo_ref = PosePath3D(poses_se3=list(est.numpy())), PosePath3D(poses_se3=list(ref.numpy()))
        evo_t, theirs = best_time(lambda a=evo_est, b=evo_ref: evo_all(a, b), 1)
        pairs = [(a[k], b[k]) for a, b in zip(ours, theirs, strict=True) for k in metrics.STATISTICS]
        rel = max(abs(a - b) / max(abs(b), 1e-300) for a, b in pairs)
        diff = max(abs(a - b) for a, b in pairs)
        print(f"{n:>8} {ours_t:>10.4f} {evo_t:>10.3f} {evo_t / ours_t:>9.1f}x {rel:>13.1e} {diff:>13.1e}")


if __name__ == "__main__":
    main()
