"""``python -m lossvo.metrics GT_FILE EST_FILE [--align ...] [--delta N] [--json]``: APE, RPE and the KITTI
odometry error of an estimated trajectory (:mod:`lossvo.evaluation.metrics`), as a table or JSON.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from lossvo.console import OneLineParser, UserError, emit, one_line_main
from lossvo.data.kitti import read_poses
from lossvo.evaluation.metrics import ALIGN_MODES, PAIRS_FROM, STATISTICS, evaluate, is_rpe_delta
from lossvo.evaluation.trajectories import read_tum

DESCRIPTION = "APE, RPE and the KITTI odometry error of an estimated KITTI pose file against a reference"


def format_table(result: dict[str, Any]) -> str:
    """A plain-text table of :func:`evaluate`'s result."""
    lines = [f"{'':14}" + "".join(f"{name:>12}" for name in STATISTICS)]
    for metric in ("ape", "rpe"):
        for part, unit in (("trans", "m"), ("rot_rad", "rad")):
            stats = result[metric][part]
            label = f"{metric.upper()} {part.split('_')[0]} ({unit})"
            lines.append(f"{label:14}" + "".join(f"{stats[name]:12.6g}" for name in STATISTICS))
    kitti = result["kitti"]
    if kitti["t_err_pct"] is None:
        lines.append("KITTI: sequence too short for any segment (100-800 m)")
    else:
        lines.append(
            f"KITTI: t_err {kitti['t_err_pct']:.4f} %, r_err {kitti['r_err_deg_per_100m']:.4f} deg/100 m"
        )
    return "\n".join(lines)


def read_trajectory(path: str) -> torch.Tensor:
    """(N, 4, 4) camera-to-world poses of a TUM file (``.tum``) or a KITTI pose file (any other name)."""
    poses = read_tum(path)[1] if Path(path).suffix == ".tum" else read_poses(path)
    return torch.from_numpy(poses)


@one_line_main
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m lossvo.metrics GT_FILE EST_FILE``; one-line errors with exit status 2."""
    parser = OneLineParser(prog="python -m lossvo.metrics", description=DESCRIPTION)
    parser.add_argument("gt", help="ground-truth poses: a KITTI pose file, or a TUM file (.tum)")
    parser.add_argument("est", help="estimated poses: a KITTI pose file, or a TUM file (.tum)")
    parser.add_argument("--align", choices=ALIGN_MODES, default="none", help="APE alignment (evo's)")
    parser.add_argument(
        "--delta", type=float, default=1, help="RPE delta, in frames or metres (--delta-unit)"
    )
    parser.add_argument(
        "--delta-unit", choices=("f", "m"), default="f", help="RPE delta unit: frames or metres"
    )
    parser.add_argument(
        "--pairs-from",
        choices=PAIRS_FROM,
        default="estimate",
        help="whose path picks RPE pairs in metres (evo: pairs_from_reference)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = parser.parse_args(argv)
    frames = args.delta_unit == "f"
    delta = int(args.delta) if frames and float(args.delta).is_integer() else args.delta
    if not is_rpe_delta(delta, args.delta_unit):
        unit = "an integer number of frames >= 1" if frames else "a distance in metres > 0"
        parser.error(f"--delta: expected {unit}, got {args.delta:g}")
    gt, est = read_trajectory(args.gt), read_trajectory(args.est)
    if len(gt) != len(est):
        raise UserError(
            f"{args.est} has {len(est)} poses, {args.gt} has {len(gt)}: expected one pose "
            f"per frame of the same sequence in both"
        )
    result = evaluate(gt, est, args.align, delta, args.delta_unit, args.pairs_from)
    emit(json.dumps(result, indent=2) if args.json else format_table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
