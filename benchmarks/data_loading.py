"""Window loading speed: lossvo's memory-mapped frame cache vs decoding + resizing PNGs per sample.

Run: ``.venv/bin/python benchmarks/data_loading.py [--root KITTI_ROOT --sequences 00] [--height 184
--width 608]``. Without ``--root`` it renders two synthetic sequences into a temporary folder, at the
generator's default resolution or at KITTI's (``--render-height 376 --render-width 1241``). Both
loaders produce the same normalised windows (seq_len, 3, H, W) in the same order through a DataLoader
with the same workers; the script prints frames/s of each and the ratio.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from lossvo.data import synthetic
from lossvo.data.datamodules import VODataModule


class PngWindows(Dataset):
    """The same windows as the cache's, decoded and resized from PNG files on every access."""

    def __init__(self, dm: VODataModule, split: str) -> None:
        """Windows of ``dm``'s ``split`` (its set-up datasets give the same indices and targets)."""
        self.cached = dm.datasets[split]
        self.images = [dm.sequences[n].images for n in dm.splits[split]]
        self.size = (dm.frames.width, dm.frames.height)

    def __len__(self) -> int:
        return len(self.cached)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        seq, start, stop, step = (int(v) for v in self.cached.index[i])
        paths = self.images[seq][start:stop:step]
        frames = [cv2.cvtColor(cv2.resize(cv2.imread(str(p)), self.size, interpolation=cv2.INTER_AREA),
                               cv2.COLOR_BGR2RGB).transpose(2, 0, 1) for p in paths]  # fmt: skip
        return {"frames": torch.from_numpy(np.stack(frames)), "K": self.cached.intrinsics[seq],
                "targets": self.cached.targets[step][seq][start : stop - 1 : step]}  # fmt: skip


def frames_per_second(
    dm: VODataModule, dataset: Dataset, batch_size: int, workers: int, repeats: int = 3
) -> float:
    """Frames per second until normalised float batches are ready, as the model receives them
    (median over ``repeats`` epochs)."""
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, num_workers=workers)
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        n = sum(dm.on_after_batch_transfer(batch, 0)["frames"].shape[:2].numel() for batch in loader)
        rates.append(n / (time.perf_counter() - start))
    return float(np.median(rates))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", help="a KITTI-layout root (default: render synthetic sequences)")
    parser.add_argument("--sequences", default="00,01")
    parser.add_argument("--height", type=int, default=64)
    parser.add_argument("--width", type=int, default=208)
    parser.add_argument("--seq-len", type=int, default=6)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--render-height", type=int, default=synthetic.DEFAULT_HEIGHT)
    parser.add_argument("--render-width", type=int, default=synthetic.DEFAULT_WIDTH)
    parser.add_argument("--frames", type=int, default=None, help="synthetic frames per sequence")
    args = parser.parse_args()
    names = args.sequences.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.root or synthetic.generate(
            Path(tmp) / "synthetic",
            sequences=names,
            frames=args.frames,
            height=args.render_height,
            width=args.render_width,
            progress=False,
        )
        dm = VODataModule(
            sources={"kitti": {"layout": "kitti", "root": str(root)}},
            splits={"train": names, "val": names, "test": names},
            frames={"height": args.height, "width": args.width, "cache_dir": str(Path(tmp) / "cache")},
            windows={"seq_len": args.seq_len, "batch_size": args.batch_size},
            loader={"num_workers": args.workers},
        )
        dm.prepare_data()
        dm.setup("fit")
        source = cv2.imread(str(dm.sequences[names[0]].images[0])).shape[:2]
        print(f"{len(dm.datasets['train'])} windows of {args.seq_len} frames, PNGs {source[1]}x{source[0]} "
              f"-> {args.width}x{args.height}, batch {args.batch_size}, {args.workers} workers, "
              f"torch {torch.get_num_threads()} threads")  # fmt: skip
        png = frames_per_second(dm, PngWindows(dm, "train"), args.batch_size, args.workers)
        cache = frames_per_second(dm, dm.datasets["train"], args.batch_size, args.workers)
    print(f"PNG decode + resize per sample: {png:10.0f} frames/s")
    print(f"lossvo frame cache (memmap):    {cache:10.0f} frames/s")
    print(f"ratio cache / PNG:              {cache / png:10.1f}x")


if __name__ == "__main__":
    main()
