"""The study entry (``python -m lossvo.study``): its plan, seed warning and estimate; several jobs at once on
one GPU (:mod:`lossvo.training.gpu_jobs`), decided from injected free memory and cores; the GPU checks
before a sweep (the ``hydra.callbacks.gpu_jobs`` callback), with ``torch.cuda`` patched where a GPU is
pretended."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig, open_dict

from helpers import train_main
from lossvo import study
from lossvo.console import UserError
from lossvo.train import CONFIG_DIR
from lossvo.training import gpu_jobs
from lossvo.training.config_checks import check_accelerator
from test_train import tiny_overrides

GIB = gpu_jobs.GIB
NO_GPU = "no CUDA GPU here (torch.cuda.is_available() is false): use trainer=default to train on the CPU"


# -- jobs at once on one GPU -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("free_gib", "cpus", "fit"),
    [(139, 16, 16), (139, 64, 34), (20, 16, 5), (3.9, 16, 0), (4, 1, 1)],
)
def test_jobs_that_fit_is_the_smaller_of_cores_and_memory(free_gib: float, cpus: int, fit: int) -> None:
    assert gpu_jobs.jobs_that_fit(int(free_gib * GIB), 4 * GIB, cpus) == fit


def test_jobs_that_fit_their_memory_pass() -> None:
    gpu_jobs.check_jobs_fit(16, 16, 139 * GIB, 4 * GIB)
    gpu_jobs.check_jobs_fit(32, 32, 128 * GIB, 4 * GIB)  # exactly full


def test_jobs_beyond_the_free_memory_are_refused_naming_key_jobs_and_memory() -> None:
    with pytest.raises(gpu_jobs.GpuMemoryError) as refused:
        gpu_jobs.check_jobs_fit(40, 40, 130 * GIB, 4 * GIB)
    assert str(refused.value) == (
        "hydra.launcher.n_jobs=40: 40 jobs at once on the GPU need 160.0 GiB at 4 GiB a job "
        "(hydra.callbacks.gpu_jobs.job_memory_gib), but it has 130.0 GiB free: 32 fit; "
        "set hydra.launcher.n_jobs=32 or lower"
    )


def test_not_one_job_fitting_asks_for_free_memory() -> None:
    with pytest.raises(gpu_jobs.GpuMemoryError, match="0 fit; free GPU memory first"):
        gpu_jobs.check_jobs_fit(1, 1, 2 * GIB, 4 * GIB)


def test_jobs_at_once_reads_n_jobs_as_joblib_does_and_counts_the_sweep() -> None:
    assert gpu_jobs.jobs_at_once(-1, None) == gpu_jobs.joblib.cpu_count()
    assert gpu_jobs.jobs_at_once(10, 3) == 3
    assert gpu_jobs.jobs_at_once(2, 60) == 2


def test_sweep_jobs_are_counted_as_the_basic_sweeper_expands_them() -> None:
    assert gpu_jobs.sweep_jobs(["loss=euler,quat,chordal", "seed=0,1", "trainer=gpu"]) == 6
    assert gpu_jobs.sweep_jobs(["seed=range(0,10)"], {"model": "deepvo_small,flowvo"}) == 20
    assert gpu_jobs.sweep_jobs([]) == 1
    assert gpu_jobs.sweep_jobs(["seed=0,1", "seed=0,1,2"]) == 3  # a key given twice: the last one counts
    assert gpu_jobs.sweep_jobs(["+a=1,2", "~b", "c=[1,2]"]) == 2
    assert gpu_jobs.sweep_jobs(["optimizer.lr=interval(0.001,0.1)"]) is None  # not the basic sweeper's


@pytest.mark.parametrize(
    ("accelerator", "cuda", "on_cuda"),
    [
        ("gpu", False, True),
        ("cuda", True, True),
        ("auto", True, True),
        ("auto", False, False),
        ("cpu", True, False),
    ],
)
def test_trains_on_cuda(accelerator: str, cuda: bool, on_cuda: bool) -> None:
    assert gpu_jobs.trains_on_cuda(accelerator, cuda) is on_cuda


# -- trainer=gpu without a GPU -----------------------------------------------------------------------


def test_a_gpu_trainer_without_a_gpu_names_trainer_default() -> None:
    with pytest.raises(UserError) as refused:
        check_accelerator("gpu", False, "gpu")
    assert str(refused.value) == f"trainer=gpu: {NO_GPU}"
    with pytest.raises(UserError) as refused:
        check_accelerator("cuda", False, "default")
    assert str(refused.value) == f"trainer.accelerator=cuda: {NO_GPU}"
    check_accelerator("gpu", True, "gpu")
    check_accelerator("auto", False, "default")
    check_accelerator("cpu", False, None)


# -- the callback before a sweep -------------------------------------------------------------------


def sweep_config(overrides: list[str], task: list[str]) -> DictConfig:
    """The train config as a sweep's callbacks see it: ``overrides`` composed, ``task`` the command line's
    overrides (with sweeps, which compose does not take)."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.overrides.task = task
    return cfg


@pytest.fixture
def pretend_gpu(monkeypatch: pytest.MonkeyPatch):
    """A function pretending a CUDA GPU with ``free_gib`` GiB free (None: no GPU at all)."""

    def pretend(free_gib: float | None) -> None:
        monkeypatch.setattr(torch.cuda, "is_available", lambda: free_gib is not None)

        def free_memory() -> int:
            assert free_gib is not None, "free memory asked for without a GPU"
            return int(free_gib * GIB)

        monkeypatch.setattr(gpu_jobs, "free_memory", free_memory)

    return pretend


def run_callback(cfg: DictConfig) -> None:
    """``on_multirun_start`` of the callback the config registers under hydra.callbacks.gpu_jobs."""
    check = instantiate(cfg.hydra.callbacks.gpu_jobs)
    assert isinstance(check, gpu_jobs.GpuJobsCheck) and check.job_memory_gib == 4.0  # the stated default
    check.on_multirun_start(config=cfg)


def test_the_callback_refuses_jobs_beyond_the_gpus_memory(pretend_gpu, capsys: pytest.CaptureFixture) -> None:
    pretend_gpu(60)
    cfg = sweep_config(["trainer=gpu", "hydra/launcher=joblib", "hydra.launcher.n_jobs=40"],
                       ["trainer=gpu", "loss=euler,quat", "seed=0,1,2,3,4,5,6,7,8,9"])  # fmt: skip
    with pytest.raises(SystemExit) as ended:
        run_callback(cfg)
    assert ended.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: hydra.launcher.n_jobs=40: 20 jobs at once on the GPU need 80.0 GiB at 4")
    assert err.count("\n") == 1 and "60.0 GiB free: 15 fit" in err


def test_the_callback_passes_jobs_that_fit(pretend_gpu) -> None:
    pretend_gpu(60)
    task = ["loss=euler,quat", "seed=0,1,2,3,4,5,6,7,8,9"]
    run_callback(sweep_config(["trainer=gpu", "hydra/launcher=joblib", "hydra.launcher.n_jobs=15"], task))
    run_callback(sweep_config(["trainer=gpu", "hydra/launcher=joblib", "hydra.launcher.n_jobs=40"], task[:1]))


def test_the_callback_checks_the_memory_a_job_as_configured(pretend_gpu, capsys) -> None:
    pretend_gpu(60)
    overrides = ["trainer=gpu", "hydra/launcher=joblib", "hydra.launcher.n_jobs=10",
                 "hydra.callbacks.gpu_jobs.job_memory_gib=8"]  # fmt: skip
    cfg = sweep_config(overrides, ["seed=0,1,2,3,4,5,6,7,8,9"])
    with pytest.raises(SystemExit):
        instantiate(cfg.hydra.callbacks.gpu_jobs).on_multirun_start(config=cfg)
    assert "80.0 GiB at 8 GiB a job" in capsys.readouterr().err


def test_the_callback_checks_a_default_trainer_on_a_gpu(pretend_gpu) -> None:
    """trainer=default (accelerator auto) trains on the GPU where there is one: the same check."""
    pretend_gpu(10)
    with pytest.raises(SystemExit):
        run_callback(sweep_config(["hydra/launcher=joblib", "hydra.launcher.n_jobs=4"], ["seed=0,1,2,3"]))


@pytest.mark.parametrize(
    "overrides",
    [
        ["hydra/launcher=joblib", "hydra.launcher.n_jobs=40"],  # the CPU: no GPU to fit
        ["trainer=gpu", "hydra/launcher=submitit_slurm_lossvo"],  # SLURM: its nodes are not this machine
        ["trainer=gpu"],  # the basic launcher: one job at a time
    ],
)
def test_the_callback_leaves_cpu_slurm_and_serial_sweeps_alone(overrides: list[str], pretend_gpu) -> None:
    pretend_gpu(None if "trainer=gpu" not in overrides else 1)
    run_callback(sweep_config(overrides, ["seed=0,1"]))


def test_the_callback_refuses_a_gpu_trainer_without_a_gpu(pretend_gpu, capsys) -> None:
    pretend_gpu(None)
    with pytest.raises(SystemExit) as ended:
        run_callback(sweep_config(["trainer=gpu", "hydra/launcher=joblib"], ["trainer=gpu", "seed=0,1"]))
    assert ended.value.code == 2
    assert capsys.readouterr().err == f"error: trainer=gpu: {NO_GPU}\n"


def test_a_gpu_sweep_without_a_gpu_is_refused_before_any_job(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """``python -m lossvo.train -m trainer=gpu ...`` (in process), on a machine without a GPU."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    sweep = tmp_path / "sweep"
    args = ["-m", *tiny_overrides(tiny_kitti, tmp_path / "cache"), "trainer=gpu", "loss=euler,quat",
            "hydra/launcher=joblib", f"hydra.sweep.dir={sweep}"]  # fmt: skip
    assert train_main(args, monkeypatch) == 2
    assert capsys.readouterr().err.strip() == f"error: trainer=gpu: {NO_GPU}"
    assert not sweep.exists()


# -- the study's plan ------------------------------------------------------------------------------


def test_ten_seeds_decide_a_claim_about_three_losses() -> None:
    """A claim about three losses is two comparisons (the claimed loss against each other), Holm-corrected:
    7 seeds give 2 * 2/2^7 = 0.031 < 0.05; about two losses, one comparison: 6 seeds (2/2^6 = 0.031)."""
    assert study.seed_warning(study.SEEDS) is None and study.seed_warning(range(7)) is None
    assert study.seed_warning(range(6), ("euler", "chordal")) is None
    assert study.seed_warning(range(5), ("euler", "chordal")) is not None


def test_too_few_seeds_warn_with_the_smallest_p() -> None:
    assert study.seed_warning((0, 1, 2)) == (
        "warning: 3 seeds: no claim can be decided: the smallest two-sided p of an exact Wilcoxon test over "
        "n seeds is 2/2^n = 0.25 here, 0.5 after Holm's correction over a claim's 2 comparisons, not below "
        "0.05; 7 seeds are needed"
    )
    assert study.seed_warning(range(6)) == (
        "warning: 6 seeds: no claim can be decided: the smallest two-sided p of an exact Wilcoxon test over "
        "n seeds is 2/2^n = 0.0312 here, 0.0625 after Holm's correction over a claim's 2 comparisons, not "
        "below 0.05; 7 seeds are needed"
    )
    assert study.seed_warning((0,), ("euler", "quat")) == (
        "warning: 1 seed: no claim can be decided: the smallest two-sided p of an exact Wilcoxon test over "
        "n seeds is 2/2^n = 1 here, not below 0.05; 6 seeds are needed"
    )


def plan_of(argv: list[str], cuda: bool = False) -> study.Plan:
    args = study.parser().parse_args(argv)
    return study.plan_study(args, cuda, 4.0, study.sweep_dir_of(args))


def test_the_default_study_is_60_jobs_two_at_once_on_the_cpu() -> None:
    plan = plan_of([])
    assert plan.jobs == 60 and plan.at_once == 2 and not plan.gpu
    command = plan.sweep_commands()[0]
    assert command[1:7] == ["-m", "lossvo.train", "-m", "model=deepvo_small,flowvo",
                            "loss=euler,quat,chordal", "seed=0,1,2,3,4,5,6,7,8,9"]  # fmt: skip
    assert "hydra/launcher=joblib" in command and "hydra.launcher.n_jobs=2" in command
    assert "trainer=gpu" not in command and f"hydra.sweep.dir={plan.sweep_dir}" in command
    assert plan.report_command()[1:] == ["-m", "lossvo.report", str(plan.sweep_dir)]


def test_overrides_and_options_reach_the_sweep() -> None:
    argv = ["--seeds", "3,4", "--models", "flowvo", "--jobs", "3", "--sweep-dir", "s", "weighting=paper"]
    plan = plan_of(argv)
    assert plan.jobs == 6 and plan.at_once == 3
    assert plan.sweep_commands()[0][4:] == ["model=flowvo", "loss=euler,quat,chordal", "seed=3,4",
                                        "hydra/launcher=joblib", "hydra.launcher.n_jobs=3",
                                        "hydra.sweep.dir=s", "weighting=paper"]  # fmt: skip


def test_on_a_gpu_as_many_jobs_as_fit_run_with_trainer_gpu(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(study.joblib, "cpu_count", lambda: 16)
    monkeypatch.setattr(gpu_jobs, "free_memory", lambda: int(139 * GIB))
    plan = plan_of([], cuda=True)
    assert plan.gpu and plan.at_once == 16
    assert {"trainer=gpu", "hydra.launcher.n_jobs=16"} <= set(plan.sweep_commands()[0])
    monkeypatch.setattr(gpu_jobs, "free_memory", lambda: int(22.5 * GIB))
    assert plan_of([], cuda=True).at_once == 5
    few = ["--seeds", "0,1", "--models", "flowvo", "--losses", "euler"]
    assert plan_of(few, cuda=True).at_once == 2  # no more than its jobs
    with pytest.raises(gpu_jobs.GpuMemoryError, match=r"hydra\.launcher\.n_jobs=8: 8 jobs at once"):
        plan_of(["--jobs", "8"], cuda=True)


def test_jobs_on_a_cpu_keep_freed_memory_unless_the_environment_says_otherwise() -> None:
    cpu = plan_of([])
    gpu = dataclasses.replace(cpu, gpu=True)
    assert study.job_environment(cpu, {"PATH": "/bin"}) == {**study.KEPT_MEMORY, "PATH": "/bin"}
    own = {"MALLOC_TRIM_THRESHOLD_": "0"}
    assert study.job_environment(cpu, own)["MALLOC_TRIM_THRESHOLD_"] == "0"
    assert study.job_environment(gpu, {"PATH": "/bin"}) == {"PATH": "/bin"}


@pytest.mark.parametrize(
    "argv", [["--seeds", "a"], ["--seeds", "0,0"], ["--seeds", "-1"], ["--seeds", "0"], ["--jobs", "0"]]
)
def test_bad_options_are_one_line(argv: list[str], capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as ended:
        study.parser().parse_args(argv)
    assert ended.value.code == 2 and capsys.readouterr().err.count("\n") == 1


# -- the estimate ----------------------------------------------------------------------------------


def test_a_jobs_time_is_its_steps_and_pairs_at_the_measured_rates() -> None:
    size = study.JobSize(epochs=10, steps=970, val_pairs=808, evaluated_pairs=6300, passes=2)
    assert size.inferred_pairs == 10 * 808 * 3 + 6300 * 2
    seconds = study.job_seconds(size, study.Calibration(step_s=0.1, pair_s=0.001), overhead_s=15.0)
    assert seconds == pytest.approx(97.0 + 36.84 + 15.0)


def test_the_study_time_shares_the_jobs_out_but_is_no_shorter_than_its_longest() -> None:
    assert study.study_seconds([100.0] * 4, 2) == 200.0
    assert study.study_seconds([10.0, 100.0], 2) == 100.0


def test_job_size_from_the_composed_config(tiny_kitti: Path, tmp_path: Path) -> None:
    """Two training sequences of 10 frames, windows of 3 frames, one at every frame: 8 each, 4 a batch: 4
    steps an epoch; 9 pairs validated (02) and evaluated (02), twice for trajectories (mirror averaging)."""
    cfg = study.compose_job("model=deepvo_small", "euler", tiny_overrides(tiny_kitti, tmp_path / "cache"))
    assert study.job_size(cfg) == study.JobSize(epochs=10, steps=40, val_pairs=9, evaluated_pairs=9, passes=2)
    tiny = [o for o in tiny_overrides(tiny_kitti, tmp_path / "cache") if not o.startswith("model.")]
    cfg = study.compose_job("model=flowvo", "quat", [*tiny, "trainer.max_epochs=2", "mirror_average=false"])
    assert study.job_size(cfg) == study.JobSize(epochs=2, steps=8, val_pairs=9, evaluated_pairs=9, passes=1)


def test_the_dry_run_prints_the_warning_the_estimate_and_the_command(
    tiny_kitti: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """In process, on the CPU: two architectures on the tiny data, measured here."""
    sweep = tmp_path / "sweep"
    overrides = [o for o in tiny_overrides(tiny_kitti, tmp_path / "cache") if not o.startswith("model.")]
    argv = ["--dry-run", "--seeds", "0,1,2", "--sweep-dir", str(sweep), *overrides]
    assert study.main(argv) == 0
    out, err = capsys.readouterr()
    assert err.startswith("warning: 3 seeds: no claim can be decided")
    lines = out.splitlines()
    assert lines[0].startswith("study: 18 jobs on the CPU (2 at once), about ")
    assert "measured on 1 thread a job: deepvo_small " in lines[0] and "; flowvo " in lines[0]
    assert lines[1].startswith("python -m lossvo.train -m model=deepvo_small,flowvo") and len(lines) == 2
    assert not sweep.exists()


def test_the_dry_run_on_a_gpu_prints_the_jobs_at_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(study.joblib, "cpu_count", lambda: 16)
    monkeypatch.setattr(gpu_jobs, "free_memory", lambda: int(139 * GIB))
    assert study.main(["--dry-run"]) == 0
    out, err = capsys.readouterr()
    assert not err
    assert out.startswith("study: 60 jobs on the GPU (16 at once: min(CPU cores, free GPU memory / 4 GiB")
    assert "trainer=gpu" in out.splitlines()[1]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--models", "resnet"],
            "--models: no model config 'resnet' (expected some of deepvo, deepvo_small, flowvo)",
        ),
        (
            ["--experiments", "mixed"],
            "--experiments: no experiment config 'mixed' (expected some of mix, paper)",
        ),
        (["--models", "none"], "--models none with no --experiments: the study has no configuration"),
    ],
)
def test_a_configuration_that_does_not_exist_is_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture
) -> None:
    assert study.main(["--dry-run", *argv]) == 2
    assert capsys.readouterr() == ("", f"error: {message}\n")


def test_an_experiment_is_a_configuration_of_its_own_in_the_same_sweep_folder() -> None:
    plan = plan_of(["--seeds", "0,1", "--experiments", "mix", "--sweep-dir", "s"])
    assert plan.configurations == ("model=deepvo_small", "model=flowvo", "experiment=mix")
    assert plan.jobs == 2 * 3 * 3
    first, second = plan.sweep_commands()
    assert first[4:7] == ["model=deepvo_small,flowvo", "loss=euler,quat,chordal", "seed=0,1"]
    assert second[4:7] == ["experiment=mix", "loss=euler,quat,chordal", "seed=0,1"]
    assert "hydra.sweep.dir=s" in first and "hydra.sweep.dir=s" in second
    (alone,) = plan_of(["--seeds", "0,1", "--models", "none", "--experiments", "mix"]).sweep_commands()
    assert alone[4] == "experiment=mix"


def test_an_experiment_on_other_data_is_evaluated_on_the_architectures_held_out_sequences(
    tmp_path: Path,
) -> None:
    """experiment=mix trains on data=mix: each completed mix job with a best checkpoint is evaluated on
    data=synthetic's sequences outside its training split, once (an evaluation already there is kept);
    the architectures' own jobs are not."""
    sweep = tmp_path / "sweep"
    plan = plan_of(["--seeds", "0,1", "--experiments", "mix", "--sweep-dir", str(sweep)])
    jobs = {"0_experiment-mix+loss-euler+seed-0": ("experiment=mix", "completed"),
            "1_experiment-mix+loss-euler+seed-1": ("experiment=mix", "running"),
            "2_experiment-mix+loss-quat+seed-0": ("experiment=mix", "completed"),
            "0_loss-euler+model-flowvo+seed-0": ("model=flowvo", "completed")}  # fmt: skip
    for name, (chosen, state) in jobs.items():
        (sweep / name / ".hydra").mkdir(parents=True)
        (sweep / name / ".hydra" / "overrides.yaml").write_text(f"- {chosen}\n- loss=euler\n")
        (sweep / name / "status.json").write_text(json.dumps({"status": state, "history": []}))
        (sweep / name / "checkpoints").mkdir()
        (sweep / name / "checkpoints" / "best.ckpt").write_bytes(b"")
    done = sweep / "evaluations" / "synthetic" / "2_experiment-mix+loss-quat+seed-0" / "results.json"
    done.parent.mkdir(parents=True)
    done.write_text("{}")
    (command,) = study.cross_evaluations(plan)
    job = sweep / "0_experiment-mix+loss-euler+seed-0"
    assert command[1:] == ["-m", "lossvo.eval", f"ckpt_path={job / 'checkpoints' / 'best.ckpt'}",
                           "data=synthetic", "data.frames.crop=true", "data.splits.test=[01,07,09,10]",
                           "data.splits.unseen=[11,12]",
                           f"hydra.run.dir={sweep / 'evaluations' / 'synthetic' / job.name}"]  # fmt: skip
    assert study.cross_evaluations(plan_of(["--seeds", "0,1", "--sweep-dir", str(sweep)])) == []


@pytest.mark.parametrize(
    ("override", "message"),
    [
        (
            "weighting=unknown",
            "In 'train': Could not find 'weighting/unknown' (available: learned, matched, paper)",
        ),
        (
            "data.windows.batch_size=abc",
            "data.windows.batch_size: expected an int, got 'abc'",
        ),  # the schema's type, at composition
        (
            "data=kitti",
            "data.sources.kitti.root: a value is required: "
            "add data.sources.kitti.root=... to the command line",
        ),
    ],
)
def test_a_bad_override_is_one_line_before_anything_is_measured(
    override: str, message: str, capsys: pytest.CaptureFixture
) -> None:
    assert study.main(["--dry-run", override]) == 2
    assert capsys.readouterr() == ("", f"error: {message}\n")


@pytest.mark.slow
def test_the_real_dry_run_command(tiny_kitti: Path, tmp_path: Path) -> None:
    """``python -m lossvo.study --dry-run --seeds 0,1 --models deepvo_small`` on the tiny data: the warning
    and the estimate, exit status 0, nothing trained."""
    env = {k: v for k, v in os.environ.items() if k != "LOSSVO_FULL_ERROR"}
    argv = [sys.executable, "-m", "lossvo.study", "--dry-run", "--seeds", "0,1", "--models",
            "deepvo_small", "--sweep-dir", str(tmp_path / "sweep"),
            *tiny_overrides(tiny_kitti, tmp_path / "cache")]  # fmt: skip
    done = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stderr.startswith("warning: 2 seeds: no claim can be decided: the smallest two-sided p")
    assert done.stdout.startswith("study: 6 jobs on the CPU (2 at once), about ")
    assert not (tmp_path / "sweep").exists()
