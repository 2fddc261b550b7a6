"""The built wheel is a complete product: configs inside the package, console scripts, no repository."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # builds, installs and runs a wheel
ROOT = Path(__file__).resolve().parents[1]


def test_wheel_holds_the_configs_and_trains_from_an_empty_folder(tmp_path: Path) -> None:
    dist, target, empty = tmp_path / "dist", tmp_path / "site", tmp_path / "empty"
    empty.mkdir()
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(dist), str(ROOT)],
                   check=True, capture_output=True)  # fmt: skip
    (wheel,) = dist.glob("lossvo-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for config in ("lossvo/conf/train.yaml", "lossvo/conf/eval.yaml", "lossvo/conf/data/synthetic.yaml",
                   "lossvo/conf/loss/chordal.yaml", "lossvo/conf/weighting/matched.yaml"):  # fmt: skip
        assert config in names, config
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    scripts = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert all(f"lossvo-{s}" in scripts for s in ("train", "eval", "report", "metrics"))

    subprocess.run([*pip, "install", "--no-deps", "--target", str(target), str(wheel)], check=True,
                   capture_output=True)  # fmt: skip
    env = {"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    where = [sys.executable, "-c", "import lossvo; print(lossvo.__file__)"]
    probe = subprocess.run(where, cwd=empty, env=env, capture_output=True, text=True, check=True)
    assert probe.stdout.strip().startswith(str(target)), (
        probe.stdout
    )  # the installed copy, not the repository
    command = [sys.executable, "-m", "lossvo.train", "--cfg", "job", "loss=euler"]
    job = subprocess.run(command, cwd=empty, env=env, capture_output=True, text=True)
    assert job.returncode == 0, job.stderr[-2000:]
    assert "_target_: lossvo.losses.EulerLoss" in job.stdout
    assert (
        "_target_: lossvo.data.datamodules.VODataModule" in job.stdout and "layout: synthetic" in job.stdout
    )
    assert not list(empty.iterdir())  # --cfg job writes nothing
    assert "hydra_plugins/lossvo_optuna_sweeper/optuna_sweeper.py" in names  # hparams_search's sweeper
    show = [sys.executable, "-m", "lossvo.train", "--cfg", "hydra", "hparams_search=k_search"]
    search = subprocess.run(show, cwd=empty, env=env, capture_output=True, text=True)
    assert search.returncode == 0, search.stderr[-2000:]
    assert "_target_: hydra_plugins.lossvo_optuna_sweeper.optuna_sweeper.LossvoOptunaSweeper" in search.stdout
