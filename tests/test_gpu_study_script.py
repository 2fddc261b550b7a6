"""benchmarks/gpu_study.py, the prepared GPU run of the decided study: its quick CPU run (tiny sizes, eager
steps, one seed of the study on the tiny dataset) goes through every stage and writes every number."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_study.py"


DEADLINE = 1800
"""Seconds the quick run may take before a stage is skipped (the script's default, 450 s, is a GPU run's
budget): a loaded CPU slows it down, and every stage must still run."""


@pytest.mark.slow
@pytest.mark.timeout(DEADLINE + 600)
def test_quick_run_goes_through_every_stage(tiny_kitti: Path, tmp_path: Path) -> None:
    data = [
        "data=kitti",
        f"data.sources.kitti.root={tiny_kitti}",
        f"data.frames.cache_dir={tmp_path / 'cache'}",
        "data.splits.train=[00,01]",
        "data.splits.val=[02]",
        "data.splits.test=[02]",
        "data.frames.height=64",
        "data.frames.width=96",
        "data.loader.num_workers=0",
        "model.channels=[8,8,16,16]",
        "model.hidden=16",
        "trainer.max_epochs=1",
    ]
    out = tmp_path / "out"
    command = [
        sys.executable,
        str(SCRIPT),
        "--quick",
        "--device",
        "cpu",
        "--out",
        str(out),
        "--work",
        str(tmp_path / "runs"),
        "--deadline",
        str(DEADLINE),
        "--study-models",
        "flowvo",
        "--job-overrides",
        *data,
    ]
    proc = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=DEADLINE + 300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    stages = json.loads((out / "gpu_study.json").read_text())["stages"]
    assert set(stages) == {"matrix_rate", "warmup_job", "flowvo_step", "job", "deepvo", "flowvo_step_large",
                           "study"}  # fmt: skip
    for name, stage in stages.items():
        assert "error" not in stage and "skipped" not in stage, (name, stage)
    assert stages["matrix_rate"]["bf16_tflops"] > 0
    for key in ("flowvo_step", "flowvo_step_large"):
        for mode in stages[key]["modes"].values():
            assert mode["resident_steps_per_s"]["median"] > 0 and mode["gathered_steps_per_s"]["median"] > 0
    assert (
        stages["warmup_job"]["exit"] == 0
        and stages["job"]["exit"] == 0
        and len(stages["job"]["epoch_s"]) == 1
    )
    deepvo = stages["deepvo"]
    assert set(deepvo["variants"]) == {"fp32", "bf16", "bf16 lstm-fp32"}
    assert deepvo["flops_per_step"] > deepvo["lstm_flops_per_step"] > 0 and deepvo["top_kernels_bf16"]
    for variant in deepvo["variants"].values():
        assert variant["achieved_tflops"] > 0 and variant["study"]["gpu_hours"] > 0
    study = stages["study"]
    assert study["exit"] == 0 and study["jobs"] == study["completed"] == 6 and study["report"]
    assert sorted(p.name for p in out.iterdir()) == [
        "gpu_study.json",
        "job.log",
        "study-report.md",
        "study.log",
        "warmup-job.log",
    ]  # a handful of files: what a device returns
