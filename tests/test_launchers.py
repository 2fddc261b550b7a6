"""Hydra's launcher and sweeper plugins on the tiny dataset: submitit_local and an Optuna search."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # sweeps through submitit and an Optuna study


def test_submitit_local_sweep(run_tiny_sweep_here, tmp_path: Path) -> None:
    """The sweep launched from this process; submitit runs each job in a process of its own."""
    status = run_tiny_sweep_here(
        tmp_path, tmp_path / "sweep", ["hydra/launcher=submitit_local", "loss=euler,quat"]
    )
    assert status == 0
    jobs = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir() and (p / "status.json").is_file())
    assert [j.name.split("_", 1)[0] for j in jobs] == ["0", "1"]
    for job in jobs:
        assert json.loads((job / "status.json").read_text())["status"] == "completed"
        assert (job / "results.json").is_file()


FAILING_SEARCH = """# @package _global_
hydra:
  sweeper:
    params:
      loss.k: choice(100.0)
      optimizer.lr: choice(1e30, 1e-3)
"""


def test_optuna_search_of_three_trials_goes_on_after_a_failing_one(
    run_tiny_sweep_here, tmp_path: Path
) -> None:
    """hparams_search=k_search (TPE, seed 0, SQLite) with the learning rate drawn from {1e30, 1e-3}: seed
    0 draws both in three trials; the diverging trials fail and the search still finishes, its job
    folders named short despite a dozen overrides. In process (the sweeper runs its trials in the calling
    process)."""
    (tmp_path / "conf" / "hparams_search").mkdir(parents=True)
    (tmp_path / "conf" / "hparams_search" / "failing.yaml").write_text(FAILING_SEARCH)
    long = [
        "optimizer.weight_decay=0.0",
        "trainer.log_every_n_steps=1",
        "trainer.gradient_clip_val=null",
        "data.loader.num_workers=0",
        "data.windows.batch_size=4",
        "data.windows.seq_len=3",
        "model.hidden_size=16",
        "weighting.c=100.0",
        "selection=score",
        "scheduler=cosine",
    ]
    args = ["hparams_search=[k_search,failing]", "hydra.sweeper.n_trials=3", *long]
    assert run_tiny_sweep_here(tmp_path, tmp_path / "sweep", args) == 0
    sweep = tmp_path / "sweep"
    jobs = [p for p in sweep.iterdir() if (p / ".hydra").is_dir()]
    assert len(jobs) == 3 and all(len(p.name) <= 66 for p in jobs)  # long override lists end in a hash
    assert (sweep / "optuna.db").is_file()
    assert "best_value" in (sweep / "optimization_results.yaml").read_text()
    statuses = [json.loads((j / "status.json").read_text())["status"] for j in sorted(sweep.iterdir())
                if (j / "status.json").is_file()]  # fmt: skip
    assert len(statuses) == 3 and {"completed", "failed"} == set(statuses), statuses
