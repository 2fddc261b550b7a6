"""benchmarks/gpu_path.py, the prepared GPU benchmark: it reads the settings the study runs, and its quick CPU
run (tiny sizes, one round) writes every number it promises, so that the script is ready when a GPU is."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
from hydra import compose, initialize_config_dir

from lossvo.train import CONFIG_DIR

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_path.py"


def script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gpu_path", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up there
    spec.loader.exec_module(module)
    return module


def composed(*overrides: str):
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        return compose("train", overrides=list(overrides))


def test_settings_are_what_the_study_runs() -> None:
    gpu_path = script()
    settings = gpu_path.study_settings()
    paper = composed("experiment=paper", "loss=chordal")
    assert settings["size"] == [paper.data.frames.height, paper.data.frames.width]
    for key in ("num_workers", "pin_memory"):
        assert settings[key] == paper.data.loader[key]
    assert (settings["lr"], settings["max_epochs"]) == (paper.optimizer.lr, paper.trainer.max_epochs)
    assert (settings["precision"], settings["cudnn_benchmark"]) == (
        paper.trainer.precision,
        paper.trainer.benchmark,
    )
    assert (settings["train"], settings["val"]) == (
        list(paper.data.splits.train),
        list(paper.data.splits.val),
    )
    flowvo = composed("experiment=paper", "model=flowvo", "loss=chordal")  # with FlowVO's own windows
    assert (flowvo.data.windows.seq_len, flowvo.data.windows.batch_size) == (2, 20)
    assert (paper.data.windows.seq_len, paper.data.windows.batch_size) == (7, 8)
    for name, cfg in (("deepvo", paper), ("flowvo", flowvo)):
        net = gpu_path.network(name, settings, quick=False)
        assert f"{net.cls.__module__.rsplit('.', 1)[0]}.{net.cls.__name__}" == cfg.model._target_
        assert (net.seq_len, net.batch_size) == (cfg.data.windows.seq_len, cfg.data.windows.batch_size)
        assert net.shipped_layout == ("channels_last" if cfg.model.channels_last else "contiguous")
        for key, value in net.kwargs.items():
            assert cfg.model[key] == value, key
    for name, target in settings["losses"].items():
        loss = gpu_path.loss_of(target)
        assert loss.k == composed("experiment=paper", f"loss={name}").loss.k
    counts = gpu_path.study_windows(settings, 7)  # every 7-frame window of 00 02-06 08; 07 and 09 tiled
    assert counts == {"train": 4541 + 4661 + 801 + 271 + 2761 + 1101 + 4071 - 7 * 6, "val": 184 + 265}


@pytest.mark.slow
def test_quick_run_writes_every_number(tmp_path: Path) -> None:
    out = tmp_path / "gpu.json"
    proc = subprocess.run(
        [sys.executable, str(SCRIPT), "--quick", "--device", "cpu", "--out", str(out)],
        capture_output=True, text=True, cwd=tmp_path, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(out.read_text())
    assert {"date", "device", "torch", "cuda", "cpu_count"} <= set(report["machine"])
    assert [case["network"] for case in report["cases"]] == ["deepvo", "flowvo"]
    for case in report["cases"]:
        assert case["best"] in case["settings"] and case["shipped"] in case["settings"]
        assert len(case["settings"]) == 4  # fp32 and bf16, channels-last and contiguous
        for entry in case["settings"].values():
            assert "error" not in entry
            for key in ("steps_per_s", "windows_per_s", "eval_windows_per_s"):
                assert entry[key]["median"] > 0, key
            assert entry["study"]["gpu_hours"] > 0
        cache = case["frame_cache"]
        assert cache["loader_windows_per_s"] > 0 and cache["fed_windows_per_s"] > 0
        assert cache["loader_over_training"] > 0 and cache["study_fed"]["gpu_hours"] > 0
    losses = report["cases"][0]["losses"]
    assert set(losses["per_loss"]) == {"euler", "quat", "chordal"}
    assert losses["study_gpu_hours"] == pytest.approx(
        sum(entry["run"]["gpu_hours"] for entry in losses["per_loss"].values())
    )
    assert "every number in" in proc.stdout


def test_a_case_whose_frame_cache_check_the_deadline_skipped_prints(capsys: pytest.CaptureFixture) -> None:
    """A deadline that skips the frame-cache check leaves a case without loader figures: its table prints."""
    setting = {"steps_per_s": {"median": 2.0, "min": 1.0, "max": 3.0}, "windows_per_s": {"median": 16.0},
               "eval_windows_per_s": {"median": 40.0}, "peak_bytes": None,
               "study": {"gpu_hours": 1.5}}  # fmt: skip
    name = "fp32 contiguous"
    case = {"network": "flowvo", "size": [64, 208], "parameters": 9e5, "batch_size": 20, "seq_len": 2,
            "windows_per_epoch": {"train": 100, "val": 10}, "settings": {name: setting}, "best": name,
            "shipped": name, "frame_cache": {"skipped": "deadline"}}  # fmt: skip
    script().print_case(case)
    assert "frame cache: skipped (deadline)" in capsys.readouterr().out
