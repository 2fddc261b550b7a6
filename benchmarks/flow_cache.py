"""The optical-flow cache of a dataset: how long each flow setting takes to build it and how large it is.

Run: ``.venv/bin/python benchmarks/flow_cache.py [--rounds 2] [--settings dis-medium dis-medium-x1.5 ...]``
(``-xS``: ``data.flow.scale=S``, the flow computed on the source images at S times the cached size).
It reads the default synthetic dataset's frame cache (the default ``data=synthetic`` config: 6,300 frames
at 64x208, under ``$LOSSVO_CACHE``, rendered first if missing), then builds the flow cache of each setting
(consecutive pairs of every sequence, each training frame step's pairs of the training ones) into a fresh
temporary folder, the settings in turn, round after round (a slower spell of the machine touches all
of them), and prints each setting's median build time, its spread, its pairs per second and its size.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from lossvo.data import flow
from lossvo.data.datamodules import VODataModule
from lossvo.train import CONFIG_DIR


def _datamodule() -> VODataModule:
    """The default config's datamodule (data=synthetic), frames cached."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("train")
    dm: VODataModule = instantiate(cfg.data)
    dm.prepare_data()
    return dm


def _build(dm: VODataModule, setting: flow.FlowSetting, folder: Path) -> tuple[float, int, int]:
    """Seconds to build every flow array the datamodule needs into ``folder``; pairs; bytes."""
    start = time.perf_counter()
    pairs = 0
    for name, steps in dm.flow_steps().items():
        frames = dm.sequence_frames(name)
        source = {"frames": name}  # a fresh folder: nothing to compare with
        for step in steps:
            images = dm.sequences[name].images
            fields = flow.ensure_flow(folder, name, frames, source, step, setting, images, progress=False)
            pairs += len(fields)
    seconds = time.perf_counter() - start
    return seconds, pairs, sum(p.stat().st_size for p in folder.glob("*.npy"))


def _setting(name: str) -> flow.FlowSetting:
    """``dis-medium`` or ``dis-medium-x1.5`` as a setting."""
    _, _, scale = name.partition("-x")
    return flow.FlowSetting("dis", float(scale or 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--settings", nargs="+", default=["dis-medium", "dis-medium-x1.5", "dis-medium-x2"])
    args = parser.parse_args()
    settings = [_setting(name) for name in args.settings]
    with tempfile.TemporaryDirectory() as tmp:
        dm = _datamodule()
        times: dict[str, list[float]] = {s.key: [] for s in settings}
        sizes: dict[str, tuple[int, int]] = {}
        for _ in range(args.rounds):
            for setting in settings:
                folder = Path(tmp) / "flow" / setting.key
                seconds, pairs, size = _build(dm, setting, folder)
                times[setting.key].append(seconds)
                sizes[setting.key] = (pairs, size)
                shutil.rmtree(folder)
    print(f"{'setting':<16} {'median s':>9} {'min-max s':>13} {'pairs/s':>8} {'pairs':>7} {'MB':>6}")
    for key, values in times.items():
        pairs, size = sizes[key]
        median = statistics.median(values)
        print(f"{key:<16} {median:9.1f} {min(values):6.1f}-{max(values):<6.1f} {pairs / median:8.0f} "
              f"{pairs:7d} {size / 1e6:6.0f}")  # fmt: skip


if __name__ == "__main__":
    main()
