"""Per-frame motion statistics of a dataset's ground truth, by split: how fast and how sharply it moves.

For each consecutive pair the relative pose ``inv(T_w_k) @ T_w_{k+1}`` gives a speed (its translation's
norm, m/frame) and a rotation (its angle, rad/frame). A split's row pools its sequences' pairs: mean, RMS,
5th/50th/95th percentiles and maximum of each, and the fraction of pairs standing still (< 1 cm).

Command line: ``python -m lossvo.data.motion [ROOT] [--train 00,02 --val 07,09 --test ... --unseen 11,12]``
for a KITTI root (default: the embedded synthetic dataset), ``--layout tum|euroc|tartanair|mimir
[--sequences A,B]`` for another layout; a Markdown table, one row per split, then one per sequence. Per
frame, so datasets recorded at different rates differ by that too (docs/data.md).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from lossvo import geometry, table_render
from lossvo.console import OneLineParser, UserError, emit, one_line_main
from lossvo.data import frame_cache, kitti, layouts, sequence
from lossvo.data.datamodules import PAPER_TEST, PAPER_TRAIN, PAPER_VAL
from lossvo.data.synthetic import routes
from lossvo.table_render import Rows

STANDING = 0.01
"""Metres per frame below which a pair counts as standing still."""
PAPER_SPLITS = {"train": PAPER_TRAIN, "val": PAPER_VAL, "test": PAPER_TEST, "unseen": routes.UNSEEN_SEQUENCES}
"""The default splits: the paper's, plus the synthetic dataset's unseen-motion sequences."""
COLUMNS = (
    "pairs",
    "speed mean",
    "speed RMS",
    "speed p5",
    "speed p50",
    "speed p95",
    "speed max",
    "standing",
    "rot mean",
    "rot RMS",
    "rot p50",
    "rot p95",
    "rot max",
)
"""Table columns: speeds in m/frame, rotations in rad/frame, standing as a fraction of the pairs."""


def frame_motion(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed (N-1,) m/frame and rotation angle (N-1,) rad/frame between consecutive poses (N, 4, 4).

    The angle is :func:`lossvo.geometry.rotation_angle` of the relative rotation (accurate at small and
    large angles).
    """
    rel = kitti.relative_targets(np.asarray(poses, dtype=np.float64))
    angle = geometry.rotation_angle(torch.from_numpy(rel[:, :3, :3])).numpy()
    return np.linalg.norm(rel[:, :3, 3], axis=1), angle


def statistics(speed: np.ndarray, rotation: np.ndarray) -> dict[str, float]:
    """The :data:`COLUMNS` of pooled pairs: speed (P,) m/frame, rotation (P,) rad/frame."""
    p5, p50, p95 = np.percentile(speed, [5, 50, 95])
    r50, r95 = np.percentile(rotation, [50, 95])
    values = (
        len(speed),
        speed.mean(),
        np.sqrt((speed**2).mean()),
        p5,
        p50,
        p95,
        speed.max(),
        (speed < STANDING).mean(),
        rotation.mean(),
        np.sqrt((rotation**2).mean()),
        r50,
        r95,
        rotation.max(),
    )
    return dict(zip(COLUMNS, map(float, values), strict=True))


def split_statistics(
    motion: Mapping[str, tuple[np.ndarray, np.ndarray]], splits: Mapping[str, Sequence[str]]
) -> dict[str, dict[str, float]]:
    """Rows {label: statistics}: one per non-empty split (its sequences' pairs pooled), then one per sequence.

    motion: {sequence: (speed, rotation)} as :func:`frame_motion` returns them.
    """
    rows = {}
    for split, names in splits.items():
        present = [n for n in names if n in motion]
        if present:
            speed = np.concatenate([motion[n][0] for n in present])
            rotation = np.concatenate([motion[n][1] for n in present])
            rows[f"{split} ({', '.join(present)})"] = statistics(speed, rotation)
    for name in sorted(motion):
        rows[name] = statistics(*motion[name])
    return rows


def markdown(rows: Mapping[str, Mapping[str, float]]) -> str:
    """A Markdown table of statistics rows: speeds m/frame, rotations rad/frame, standing in percent."""

    def cell(column: str, value: float) -> str:
        if column == "pairs":
            return f"{value:.0f}"
        if column == "standing":
            return f"{100 * value:.1f} %"
        return f"{value:.3f}" if column.startswith("speed") else f"{value:.4f}"

    head = ["split / sequence", *COLUMNS]
    cells = [[label, *(cell(c, row[c]) for c in COLUMNS)] for label, row in rows.items()]
    return table_render.markdown(Rows(head, cells))


def read_motion(root: Path, names: Sequence[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{sequence: (speed, rotation)} of the sequences under root that have a poses file."""
    motion = {}
    for name in names:
        path = kitti.pose_path(root, name)
        if path.is_file():
            motion[name] = frame_motion(kitti.read_poses(path))
    return motion


def read_layout_motion(
    layout: str, root: Path, names: Sequence[str]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{sequence: (speed, rotation)} of sequences read by the ``layout``'s reader
    (:mod:`lossvo.data.layouts`): every one found under ``root`` when ``names`` is empty."""
    chosen = list(names) or layouts.list_sequences(layout, root)
    poses = {name: layouts.load_sequence(layout, root, name).poses for name in chosen}
    return {name: frame_motion(p) for name, p in poses.items() if p is not None}


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m lossvo.data.motion", description=__doc__.split("\n\n")[0])
    default_root = "the synthetic dataset in the lossvo cache"
    p.add_argument("root", nargs="?", type=Path, default=None, help=f"dataset root (default: {default_root})")
    p.add_argument(
        "--layout", default="kitti", choices=layouts.LAYOUTS, help="the dataset's layout (default: kitti)"
    )
    p.add_argument(
        "--sequences", default="", help="with --layout other than kitti: the sequences (default: all)"
    )
    for split, names in PAPER_SPLITS.items():
        p.add_argument(f"--{split}", default=None, help=f"sequences (default: {','.join(names)})")
    return p


@one_line_main
def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point: prints the table; exit status 2 and one line for a bad root or split."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.layout != "kitti":
        if args.root is None:
            parser.error(f"--layout {args.layout}: give the dataset root (python -m lossvo.data.motion ROOT)")
        try:
            motion = read_layout_motion(args.layout, args.root, sequence.sequence_names(args.sequences))
        except UserError as err:  # DatasetFormatError
            parser.error(str(err))
        if not motion:
            parser.error(f"{args.root}: no {args.layout} sequence found")
        emit(markdown(split_statistics(motion, {"all": list(motion)})))
        return 0
    root = args.root or frame_cache.default_cache_dir() / "synthetic"
    try:
        root = kitti.find_root(root)
        given = {s: getattr(args, s) for s in PAPER_SPLITS if getattr(args, s) is not None}
        splits = {s: sequence.sequence_names(given.get(s, ",".join(n))) for s, n in PAPER_SPLITS.items()}
        motion = read_motion(root, sorted({n for names in splits.values() for n in names}))
    except UserError as err:  # KittiFormatError too
        parser.error(str(err))
    if not motion:
        parser.error(f"{root}: no poses file for any of the requested sequences")
    for split in given:  # a split the user named must exist; the defaults' missing ones are left out
        missing = [n for n in splits[split] if n not in motion]
        if missing:
            parser.error(f"--{split}: {root} has no poses file for {', '.join(missing)} (poses/NN.txt)")
    emit(markdown(split_statistics(motion, splits)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
