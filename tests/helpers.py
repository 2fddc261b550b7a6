"""Test helpers that import torch and Lightning: devices to test on, entry points run in this process."""

from __future__ import annotations

import csv
import json
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from lossvo import eval as lossvo_eval
from lossvo import train
from lossvo.data.datamodules import VODataModule
from lossvo.training import fitting, lifecycle

DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA is not available")
    ),
]


SPEC_OF = {
    **dict.fromkeys(("train", "val", "test", "unseen"), "splits"),
    **dict.fromkeys(("height", "width", "crop", "normalization", "statistics", "cache_dir"), "frames"),
    **dict.fromkeys(("seq_len", "frame_steps", "batch_size", "per_epoch"), "windows"),
    **dict.fromkeys(("num_workers", "pin_memory", "on_device", "device_budget_gb"), "loader"),
    **dict.fromkeys(("method", "scale"), "flow"),
}
"""The spec of each keyword of :func:`data_module`; any other keyword is the source's."""
RENAMED = {"windows_per_epoch": "per_epoch", "flow": "method", "flow_scale": "scale"}
RENAMED["frames"] = "frame_counts"


def data_module(root: str | Path, layout: str = "kitti", **keys: object) -> VODataModule:
    """A data module of one dataset named ``layout``, each keyword (``height=32``, ``train=[...]``,
    ``on_device=False``, the synthetic source's ``frames=6``) put into its spec; ``transforms`` as given."""
    config: dict[str, dict] = {"sources": {layout: {"layout": layout, "root": str(root)}}}
    for key, value in keys.items():
        key = RENAMED.get(key, key)
        if key == "transforms":
            config[key] = value  # type: ignore[assignment]
            continue
        spec = config["sources"][layout] if key not in SPEC_OF else config.setdefault(SPEC_OF[key], {})
        spec[key] = value
    return VODataModule(**config)


def exit_status(error: SystemExit) -> int:
    """The exit status the interpreter gives a SystemExit: 0 for None, the int, 1 for a message."""
    return 0 if error.code is None else error.code if isinstance(error.code, int) else 1


def run_hydra_main(main: Callable[[], object], argv: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    """Run a Hydra entry point (``train.main``, ``eval.main``) in this process as the command line ``argv``
    would, a subprocess costing seconds of imports: its exit status. Hydra's global state is cleared
    afterwards; exceptions other than SystemExit propagate."""
    monkeypatch.setattr(sys, "argv", argv)
    try:
        main()
    except SystemExit as e:
        return exit_status(e)
    finally:
        GlobalHydra.instance().clear()
    return 0


def train_main(args: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    """``python -m lossvo.train ARGS`` in this process: its exit status."""
    return run_hydra_main(train.main, ["lossvo.train", *args], monkeypatch)


def eval_main(args: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
              ) -> tuple[int, str]:  # fmt: skip
    """``python -m lossvo.eval ARGS`` in this process: (exit status, stderr)."""
    return run_hydra_main(lossvo_eval.main, ["lossvo.eval", *args], monkeypatch), capsys.readouterr().err


def fit(cfg: DictConfig) -> dict[str, float]:
    """:func:`lossvo.training.fitting.train` in the output folder a composed config names
    (``test_train.compose_train``), as a fresh run: the trainer's final callback metrics."""
    out = Path(HydraConfig.get().runtime.output_dir)
    return fitting.train(cfg, lifecycle.Run(cfg, out, "run", fresh=True))


def metrics_rows(run: Path) -> list[dict[str, str]]:
    """The rows of a job folder's ``metrics.csv``."""
    with (run / "metrics.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def status_of(run: Path) -> dict:
    """A job folder's ``status.json``."""
    return json.loads((run / "status.json").read_text())


def scores_of(run: Path) -> dict:
    """A job folder's ``results.json`` without the path of the checkpoint it evaluated."""
    return {k: v for k, v in json.loads((run / "results.json").read_text()).items() if k != "checkpoint"}


def check_ape_against_evo(folder: Path, stem: str, ape_rmse: float, frames: int) -> None:
    """``evo_ape tum <stem>_gt.tum <stem>.tum`` in ``folder`` (evo's association by time, no alignment)
    gives ``ape_rmse`` (m) over ``frames`` poses."""
    from evo.core import sync
    from evo.core.metrics import APE, PoseRelation, StatisticsType
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(folder / f"{stem}_gt.tum"))
    est = file_interface.read_tum_trajectory_file(str(folder / f"{stem}.tum"))
    ref, est = sync.associate_trajectories(ref, est)
    assert ref.num_poses == est.num_poses == frames
    ape = APE(PoseRelation.translation_part)
    ape.process_data((ref, est))
    assert ape.get_statistic(StatisticsType.rmse) == pytest.approx(ape_rmse, rel=1e-6)
