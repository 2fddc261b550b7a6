"""Sweep job folder names: the swept keys first, then the other overrides, then (when long) a hash;
pasteable unquoted into an override."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from lossvo.training.resolvers import MAX_NAME, job_name, swept_keys

COMMAND = ["loss=euler,chordal", "trainer.max_epochs=1", "data.windows.per_epoch=16", "data.splits.test=[07]",
           "data.splits.unseen=[11]"]  # fmt: skip


def test_swept_keys_are_those_with_several_values() -> None:
    assert swept_keys(["-m", *COMMAND, "seed=range(3)", "hydra/launcher=joblib"]) == ["loss", "seed"]
    assert swept_keys(["data.splits.test=[07,08]", "model=deepvo"]) == []  # a list is one value


def test_the_swept_key_comes_first_and_survives_the_length_limit() -> None:
    job = ["loss=euler", *COMMAND[1:]]
    name = job_name(job, "loss")
    assert name.startswith("loss-euler+data.splits.test-07+data.splits.unseen-11")
    assert len(name) <= MAX_NAME and "=" not in name
    assert job_name(["loss=chordal", *COMMAND[1:]], "loss").startswith("loss-chordal+")
    assert job_name(["seed=0", "loss=euler"], "loss,seed") == "loss-euler+seed-0"  # the default sweep's
    assert (
        job_name(
            ["seed=0", "data.sources.kitti.root=/x", "+evaluate=false"], "seed", ["data.sources.kitti.root"]
        )
        == "seed-0++evaluate-false"  # as Hydra writes an added key
    )


def test_a_real_sweep_names_its_jobs_by_the_swept_key(tmp_path: Path) -> None:
    """Jobs refused by the network's check keep their folders (marked failed): the names cost no training.
    (The sweep's own check composes configs and checks data settings, not the network's arguments.)"""
    sweep = tmp_path / "sweep"
    env = {**os.environ, "LOSSVO_CACHE": str(tmp_path / "cache")}
    env.pop("LOSSVO_FULL_ERROR", None)
    command = [
        sys.executable,
        "-m",
        "lossvo.train",
        "-m",
        *COMMAND,
        "model.hidden_size=0",
        f"hydra.sweep.dir={sweep}",
    ]
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 2, done.stdout + done.stderr
    assert (
        done.stderr.strip().splitlines()[-1]
        == "error: job 1/2 (loss=euler trainer.max_epochs=1 data.windows.per_epoch=16 data.splits.test=[07] "
        "data.splits.unseen=[11] model.hidden_size=0) failed (its line is above and in its status.json); "
        f"the sweep's other jobs ran: python -m lossvo.report {sweep} tables them"
    )
    names = sorted(p.name for p in sweep.iterdir() if p.is_dir())
    assert [name[:15] for name in names] == ["0_loss-euler+da", "1_loss-chordal+"], names
