"""``python -m lossvo.motion [ROOT] [--train 00,02 ...]``: the per-frame motion statistics of a dataset's
ground truth (:mod:`lossvo.data.motion`) as a Markdown table, per split, then per sequence (docs/data.md).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from lossvo import table_render
from lossvo.console import OneLineParser, UserError, emit, one_line_main
from lossvo.data import frame_cache, kitti, layouts, motion, sequence
from lossvo.data.datamodules import PAPER_TEST, PAPER_TRAIN, PAPER_VAL
from lossvo.data.synthetic import routes
from lossvo.table_render import Rows

PAPER_SPLITS = {"train": PAPER_TRAIN, "val": PAPER_VAL, "test": PAPER_TEST, "unseen": routes.UNSEEN_SEQUENCES}
"""The default splits: the paper's, plus the synthetic dataset's unseen-motion sequences."""


def markdown(rows: Mapping[str, Mapping[str, float]]) -> str:
    """A Markdown table of statistics rows: speeds m/frame, rotations rad/frame, standing in percent."""

    def cell(column: str, value: float) -> str:
        if column == "pairs":
            return f"{value:.0f}"
        if column == "standing":
            return f"{100 * value:.1f} %"
        return f"{value:.3f}" if column.startswith("speed") else f"{value:.4f}"

    head = ["split / sequence", *motion.COLUMNS]
    cells = [[label, *(cell(c, row[c]) for c in motion.COLUMNS)] for label, row in rows.items()]
    return table_render.markdown(Rows(head, cells))


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m lossvo.motion", description=(motion.__doc__ or "").split("\n\n")[0])
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
    """Print the table; one line and exit status 2 for a bad root or split."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.layout != "kitti":
        if args.root is None:
            parser.error(f"--layout {args.layout}: give the dataset root (python -m lossvo.motion ROOT)")
        try:
            found = motion.read_layout_motion(args.layout, args.root, sequence.sequence_names(args.sequences))
        except UserError as err:  # DatasetFormatError
            parser.error(str(err))
        if not found:
            parser.error(f"{args.root}: no {args.layout} sequence found")
        emit(markdown(motion.split_statistics(found, {"all": list(found)})))
        return 0
    root = args.root or frame_cache.default_cache_dir() / "synthetic"
    try:
        root = kitti.find_root(root)
        given = {s: getattr(args, s) for s in PAPER_SPLITS if getattr(args, s) is not None}
        splits = {s: sequence.sequence_names(given.get(s, ",".join(n))) for s, n in PAPER_SPLITS.items()}
        found = motion.read_motion(root, sorted({n for names in splits.values() for n in names}))
    except UserError as err:  # KittiFormatError too
        parser.error(str(err))
    if not found:
        parser.error(f"{root}: no poses file for any of the requested sequences")
    for split in given:  # a split the user named must exist; the defaults' missing ones are left out
        missing = [n for n in splits[split] if n not in found]
        if missing:
            parser.error(f"--{split}: {root} has no poses file for {', '.join(missing)} (poses/NN.txt)")
    emit(markdown(motion.split_statistics(found, splits)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
