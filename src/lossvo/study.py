"""``python -m lossvo.study``: the study's sweep (seeds x architectures x losses), then its report.

Examples::

    python -m lossvo.study              # seeds 0-9 x deepvo_small, flowvo x euler, quat, chordal
    python -m lossvo.study --dry-run    # the plan and its time estimate; nothing trains
    python -m lossvo.study --seeds 0,1,2 --models flowvo weighting=paper selection=loss
    python -m lossvo.study --models none --experiments mix --seeds 0,1,2,3,4,5,6 --sweep-dir S

It checks the plan, estimates its time, runs the sweeps (``python -m lossvo.train -m ...``, joblib) into one
sweep folder, then ``python -m lossvo.report`` on it. The plan and its estimate: docs/sweep.md.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import shlex
import subprocess
import sys
import time
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path
from statistics import median
from typing import Any, cast

import joblib
import lightning as L
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from lightning.pytorch.callbacks import Callback
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from torch.utils.data import DataLoader, Dataset

from lossvo.console import OneLineParser, UserError, emit, one_line, one_line_main
from lossvo.data import windows
from lossvo.evaluation import job_folder
from lossvo.evaluation.inference import predict_sequence
from lossvo.report import statistics
from lossvo.report.across_datasets import EVALUATIONS
from lossvo.report.jobs import read_overrides
from lossvo.report.statistics import ALPHA
from lossvo.train import CONFIG_DIR
from lossvo.training import gpu_jobs
from lossvo.training.config_checks import check_job
from lossvo.training.module import VOModule

SEEDS = tuple(range(10))
MODELS = ("deepvo_small", "flowvo")
EXPERIMENTS: tuple[str, ...] = ()
LOSSES = ("euler", "quat", "chordal")
"""The study's default seeds, architectures (``model=``), experiments (``experiment=``) and losses."""
NONE = "none"
"""``--models none`` / ``--experiments none``: no configuration of that kind."""

CPU_JOBS = 2
"""Jobs at once on a CPU (experiments/2026-12-01-sweep-wall-time.md)."""

KEPT_MEMORY = {
    "MALLOC_MMAP_THRESHOLD_": str(32 << 20),
    "MALLOC_TRIM_THRESHOLD_": str(16 << 30),
    "MALLOC_TOP_PAD_": str(256 << 20),
}
"""glibc's settings for the jobs on a CPU: fewer page faults, the same numbers
(experiments/2026-12-07-camera-arm-cost.md)."""

JOB_OVERHEAD_S = 15.0
"""Seconds a job spends outside its training steps and inference passes (start, checkpoints, evaluation)."""

CALIBRATION_STEPS = 8
"""Training steps timed for each architecture; the first two warm up and are not counted."""


# -- the plan --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Plan:
    """A study's sweep: ``seeds`` x configurations (``models``, then ``experiments``) x ``losses``,
    ``at_once`` jobs at a time."""

    seeds: tuple[int, ...]
    models: tuple[str, ...]
    losses: tuple[str, ...]
    overrides: tuple[str, ...]
    sweep_dir: Path
    gpu: bool
    at_once: int
    experiments: tuple[str, ...] = ()

    @property
    def configurations(self) -> tuple[str, ...]:
        """Each configuration's override: ``model=deepvo_small``, ..., ``experiment=mix``."""
        return configurations(self.models, self.experiments)

    @property
    def jobs(self) -> int:
        return len(self.seeds) * len(self.configurations) * len(self.losses)

    def sweep_commands(self) -> list[list[str]]:
        """``python -m lossvo.train -m ...``: one multirun of the architectures, then one per experiment."""
        groups = [f"model={','.join(self.models)}"] if self.models else []
        return [self._sweep(group) for group in [*groups, *(f"experiment={e}" for e in self.experiments)]]

    def _sweep(self, configuration: str) -> list[str]:
        return [
            sys.executable,
            "-m",
            "lossvo.train",
            "-m",
            configuration,
            f"loss={','.join(self.losses)}",
            f"seed={','.join(map(str, self.seeds))}",
            "hydra/launcher=joblib",
            f"hydra.launcher.n_jobs={self.at_once}",
            f"hydra.sweep.dir={self.sweep_dir}",
            *(["trainer=gpu"] if self.gpu else []),
            *self.overrides,
        ]

    def report_command(self) -> list[str]:
        return [sys.executable, "-m", "lossvo.report", str(self.sweep_dir)]


def seed_warning(seeds: Sequence[int], losses: Sequence[str] = LOSSES, alpha: float = ALPHA) -> str | None:
    """The warning for too few seeds to decide a claim about ``losses`` (exact tests over seeds,
    Holm-corrected over the claim's comparisons: :mod:`lossvo.report.statistics`), else None."""
    n, m = len(seeds), max(len(losses) - 1, 1)
    if statistics.can_decide(n, m, alpha):
        return None
    needed = statistics.min_seeds(m, alpha)
    seeds_ = f"{n} seed{'s' * (n != 1)}"
    smallest = f"2/2^n = {statistics.smallest_p(n):.3g} here"
    if m > 1:
        smallest += (
            f", {statistics.smallest_holm_p(n, m):.3g} after Holm's correction over a claim's {m} comparisons"
        )
    return (
        f"warning: {seeds_}: no claim can be decided: the smallest two-sided p of an exact Wilcoxon test "
        f"over n seeds is {smallest}, not below {alpha:g}; {needed} seeds are needed"
    )


# -- what a job does, from its composed config -------------------------------------------------------


def configurations(models: Sequence[str], experiments: Sequence[str]) -> tuple[str, ...]:
    """The configurations' overrides: ``model=...`` each, then ``experiment=...`` each."""
    return (*(f"model={m}" for m in models), *(f"experiment={e}" for e in experiments))


def compose_job(configuration: str, loss: str, overrides: Sequence[str]) -> DictConfig:
    """The training config of one job (Hydra's config included, unresolved); ``configuration`` is its
    override (``model=flowvo``, ``experiment=mix``)."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        return compose(
            "train", overrides=[configuration, f"loss={loss}", *overrides], return_hydra_config=True
        )


def check_configurations(models: Sequence[str], experiments: Sequence[str]) -> None:
    """``UserError`` naming a model or experiment that has no config in ``conf/`` (and those that do)."""
    for group, names in (("model", models), ("experiment", experiments)):
        known = sorted(p.stem for p in (Path(CONFIG_DIR) / group).glob("*.yaml"))
        unknown = [name for name in names if name not in known]
        if unknown:  # the option is the group's plural
            raise UserError(
                f"--{group}s: no {group} config {unknown[0]!r} (expected some of {', '.join(known)})"
            )


@dataclass(frozen=True)
class JobSize:
    """The work of one job: ``steps`` training steps, ``val_pairs`` frame pairs validated each epoch,
    ``evaluated_pairs`` evaluated at its end, ``passes`` inference passes a pair (2 with mirror averaging)."""

    epochs: int
    steps: int
    val_pairs: int
    evaluated_pairs: int
    passes: int

    @property
    def inferred_pairs(self) -> int:
        """Pair inferences of the job: validation (losses, trajectories) each epoch, then the evaluation."""
        return self.epochs * self.val_pairs * (1 + self.passes) + self.evaluated_pairs * self.passes


def job_size(cfg: DictConfig) -> JobSize:
    """A job's :class:`JobSize`, from its composed config and the data's metadata (poses, timestamps)."""
    datamodule = instantiate(cfg.data, _convert_="all")
    datamodule.load_metadata()
    sequences, spec = datamodule.sequences, datamodule.windows
    train = sum(
        len(windows.training_starts(len(seq.times), spec.seq_len, step, windows.gaps(seq.times)))
        for seq in (sequences[name] for name in datamodule.splits["train"])
        for step in spec.frame_steps
    )
    per_epoch = min(spec.per_epoch or train, train)
    epochs = int(cfg.trainer.max_epochs)
    steps = epochs * math.ceil(per_epoch / spec.batch_size)
    max_steps = int(cfg.trainer.get("max_steps") or -1)
    pairs = {name: len(seq.times) - 1 for name, seq in sequences.items()}
    return JobSize(
        epochs=epochs,
        steps=min(steps, max_steps) if max_steps > 0 else steps,
        val_pairs=sum(pairs[name] for name in datamodule.splits["val"]),
        evaluated_pairs=sum(pairs[name] for name in datamodule.evaluated) if cfg.get("evaluate", True) else 0,
        passes=2 if cfg.get("mirror_average", True) else 1,
    )


# -- measuring on this machine ---------------------------------------------------------------------


@dataclass(frozen=True)
class Calibration:
    """One architecture's rates measured here: seconds of a training step through Lightning and of a frame
    pair's inference pass."""

    step_s: float
    pair_s: float


class _StepTimes(Callback):
    """Wall time of each training batch, seconds."""

    def __init__(self) -> None:
        self.seconds: list[float] = []
        self._start = 0.0

    def on_train_batch_start(self, *args: Any) -> None:
        self._start = time.perf_counter()

    def on_train_batch_end(self, *args: Any) -> None:
        self.seconds.append(time.perf_counter() - self._start)


def _container(node: Any) -> dict[str, Any]:
    return cast("dict[str, Any]", OmegaConf.to_container(node, resolve=True))


def job_module(cfg: DictConfig) -> VOModule:
    """The job's LightningModule, from its config (without FlowNet weights and without a schedule)."""
    model = _container(cfg.model)
    model.pop("flownet", None)
    return VOModule(model=model, loss=_container(cfg.loss), optimizer=_container(cfg.optimizer))


def random_batch(cfg: DictConfig, windows_: int, seq_len: int) -> dict[str, torch.Tensor]:
    """A random batch of ``windows_`` windows of ``seq_len`` frames as the data module hands it over."""
    h, w = int(cfg.data.frames.height), int(cfg.data.frames.width)
    K = torch.tensor([[w, 0.0, w / 2], [0.0, w, h / 2], [0.0, 0.0, 1.0]])
    return {
        "frames": torch.randn(windows_, seq_len, 3, h, w),
        "flow": torch.randn(windows_, seq_len - 1, 2, h, w),
        "K": K.expand(windows_, 3, 3).clone(),
        "targets": torch.eye(4).expand(windows_, seq_len - 1, 4, 4).clone(),
    }


@contextmanager
def _quiet() -> Iterator[None]:
    """Lightning's banners (log records below ERROR) and warnings silenced (a calibration is not a run)."""
    previous = logging.root.manager.disable
    logging.disable(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logging.disable(previous)


def time_training_step(cfg: DictConfig) -> float:
    """Median seconds of a training step on the CPU, through Lightning, on batches of the config's shape."""
    windows = cfg.data.windows
    size = (int(windows.batch_size), int(windows.seq_len))
    batches = [random_batch(cfg, *size) for _ in range(CALIBRATION_STEPS)]
    timer = _StepTimes()
    with _quiet():
        trainer = L.Trainer(
            accelerator="cpu",
            devices=1,
            max_steps=CALIBRATION_STEPS,
            limit_val_batches=0,
            num_sanity_val_steps=0,
            logger=False,
            enable_checkpointing=False,
            enable_progress_bar=False,
            enable_model_summary=False,
            callbacks=[timer],
        )
        trainer.fit(job_module(cfg), train_dataloaders=DataLoader(cast("Dataset", batches), batch_size=None))
    return median(timer.seconds[2:])


def inference_inputs(cfg: DictConfig, windows_per_pass: int = 32) -> dict[str, Any]:
    """A random sequence of ``windows_per_pass`` windows as :func:`predict_sequence` reads it."""
    batch = random_batch(cfg, 1, windows_per_pass * (int(cfg.data.windows.seq_len) - 1) + 1)
    return {name: batch[name][0].numpy() for name in ("frames", "flow", "K")}


def time_inference_pair(cfg: DictConfig) -> float:
    """Seconds of a frame pair in an inference pass over random windows
    (:func:`lossvo.evaluation.inference.predict_sequence`), after a warm-up pass."""
    inputs, module, seq_len = inference_inputs(cfg), job_module(cfg), int(cfg.data.windows.seq_len)
    predict_sequence(module, inputs, lambda loaded: loaded, seq_len)
    start = time.perf_counter()
    predict_sequence(module, inputs, lambda loaded: loaded, seq_len)
    return (time.perf_counter() - start) / (len(inputs["frames"]) - 1)


def calibrate(cfg: DictConfig, threads: int) -> Calibration:
    """:class:`Calibration` of the job's architecture on ``threads`` CPU threads."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    L.seed_everything(0, verbose=False)
    try:
        return Calibration(time_training_step(cfg), time_inference_pair(cfg))
    finally:
        torch.set_num_threads(previous)


# -- the estimate ----------------------------------------------------------------------------------


def job_seconds(size: JobSize, rate: Calibration, overhead_s: float = JOB_OVERHEAD_S) -> float:
    """Seconds one job takes: its steps and pair inferences at the measured rates, plus ``overhead_s``."""
    return size.steps * rate.step_s + size.inferred_pairs * rate.pair_s + overhead_s


def study_seconds(job_s: Sequence[float], at_once: int) -> float:
    """Seconds the jobs take ``at_once`` at a time: their sum shared out, at least the longest job."""
    return max(sum(job_s) / at_once, max(job_s, default=0.0))


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def cpu_estimate(plan: Plan) -> str:
    """The study's one line on a CPU: its jobs, how many at once, about how long, what was measured."""
    threads = max(joblib.cpu_count() // plan.at_once, 1)
    job_s, measured = [], []
    for configuration in plan.configurations:
        cfg = compose_job(configuration, plan.losses[0], plan.overrides)
        size, rate = job_size(cfg), calibrate(cfg, threads)
        job_s += [job_seconds(size, rate)] * len(plan.seeds) * len(plan.losses)
        measured.append(
            f"{configuration.split('=')[1]} {rate.step_s * 1e3:.0f} ms a step x {size.steps:,} steps + "
            f"{rate.pair_s * 1e3:.2f} ms a pair x {size.inferred_pairs:,} pairs"
        )
    total = _hours(study_seconds(job_s, plan.at_once))
    threads_a_job = f"{threads} thread{'s' * (threads > 1)} a job"
    return (
        f"study: {plan.jobs} jobs on the CPU ({plan.at_once} at once), about {total} here (measured on "
        f"{threads_a_job}: {'; '.join(measured)}; plus {JOB_OVERHEAD_S:g} s a job to start and finish; "
        f"not counted: building a missing data cache, the report)"
    )


def gpu_line(plan: Plan, job_gib: float) -> str:
    """The study's one line on a GPU: its jobs and how many at once (no time estimate)."""
    return (
        f"study: {plan.jobs} jobs on the GPU ({plan.at_once} at once: min(CPU cores, free GPU memory / "
        f"{job_gib:g} GiB a job, {gpu_jobs.JOB_MEMORY_KEY})); no time estimate: jobs at once share the "
        f"GPU (benchmarks/gpu_study.py measures them)"
    )


# -- the command line ------------------------------------------------------------------------------


def _names(text: str) -> tuple[str, ...]:
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}")
    return names


def _configurations(text: str) -> tuple[str, ...]:
    """A comma list of config names, or ``none``."""
    return () if text.strip() == NONE else _names(text)


def _seeds(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(seed) for seed in _names(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected integers >= 0 like 0,1,2, got {text!r}") from None
    if any(seed < 0 for seed in seeds) or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"expected distinct integers >= 0 like 0,1,2, got {text!r}")
    if len(seeds) < 2:
        raise argparse.ArgumentTypeError(
            f"expected at least 2 seeds (seeds are the unit of every test), got {text!r}"
        )
    return seeds


def _positive(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return int(text)


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m lossvo.study", description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=_seeds, default=SEEDS, help="comma list (default: 0-9)")
    p.add_argument(
        "--models", type=_configurations, default=MODELS, help="default: deepvo_small,flowvo; none"
    )
    p.add_argument(
        "--experiments",
        type=_configurations,
        default=EXPERIMENTS,
        help="experiments run beside the architectures, each a configuration (e.g. mix; default: none)",
    )
    p.add_argument("--losses", type=_names, default=LOSSES, help="default: euler,quat,chordal")
    p.add_argument(
        "--jobs",
        type=_positive,
        default=None,
        help=f"jobs at once (default: {CPU_JOBS} on a CPU, as many as fit on a GPU)",
    )
    p.add_argument("--sweep-dir", type=Path, default=None, help="default: outputs/multirun/<date>_<time>")
    p.add_argument("--dry-run", action="store_true", help="print the plan and its estimate; train nothing")
    p.add_argument("overrides", nargs="*", help="Hydra overrides for every job, e.g. weighting=paper")
    return p


def checked_jobs(args: argparse.Namespace, sweep_dir: Path) -> float:
    """Compose and check one job of each configuration and loss; the GPU memory one job needs, GiB."""
    check_configurations(args.models, args.experiments)
    if not args.models and not args.experiments:
        raise UserError("--models none with no --experiments: the study has no configuration")
    for configuration in configurations(args.models, args.experiments):
        for loss in args.losses:
            cfg = compose_job(configuration, loss, args.overrides)
            check_job(cfg, sweep_dir / "check")
    return float(cfg.hydra.callbacks.gpu_jobs.job_memory_gib)


def sweep_dir_of(args: argparse.Namespace) -> Path:
    """``--sweep-dir``, or ``outputs/multirun/<date>_<time>`` as Hydra names a sweep's folder."""
    return args.sweep_dir or Path("outputs/multirun") / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")


def plan_study(args: argparse.Namespace, cuda: bool, job_gib: float, sweep_dir: Path) -> Plan:
    """The :class:`Plan` of the parsed command line; on the GPU where ``cuda``, ``--jobs`` or as many jobs
    at once as fit its free memory (``UserError`` when they do not fit)."""
    plan = Plan(
        tuple(args.seeds),
        tuple(args.models),
        tuple(args.losses),
        tuple(args.overrides),
        sweep_dir,
        gpu=cuda,
        at_once=args.jobs or CPU_JOBS,
        experiments=tuple(args.experiments),
    )
    if not cuda:
        return plan
    free, job_bytes = gpu_jobs.free_memory(), int(job_gib * gpu_jobs.GIB)
    at_once = args.jobs or min(plan.jobs, gpu_jobs.jobs_that_fit(free, job_bytes, joblib.cpu_count()))
    gpu_jobs.check_jobs_fit(at_once, max(at_once, 1), free, job_bytes)
    return replace(plan, at_once=at_once)


# -- the experiments on the architectures' data ----------------------------------------------------


def _job_of(folder: Path, experiment: str) -> bool:
    """Whether a job folder is a completed job of ``experiment`` with a best checkpoint."""
    overrides = folder / ".hydra" / "overrides.yaml"
    if not (overrides.is_file() and (folder / "checkpoints" / "best.ckpt").is_file()):
        return False
    status = job_folder.read_status(folder)
    chosen = read_overrides(overrides).get("experiment") == experiment
    return chosen and status is not None and status.state == "completed"


def cross_evaluations(plan: Plan) -> list[list[str]]:
    """``python -m lossvo.eval`` of each completed job of an experiment trained on other data than the
    architectures, on the architectures' held-out sequences, into ``<sweep>/evaluations/<data>/<job>``
    (those already there are not repeated; docs/sweep.md)."""
    first = plan.configurations[0] if plan.models else f"model={MODELS[0]}"
    base = compose_job(first, plan.losses[0], [o for o in plan.overrides if not o.startswith("experiment=")])
    choice, splits = str(base.hydra.runtime.choices.data), base.data.splits
    train = set(splits.train)
    data = [o for o in plan.overrides if o.split("=")[0] == "data" or o.startswith("data.sources.")]
    test = ",".join(str(s) for s in splits.test if s not in train)
    unseen = ",".join(str(s) for s in splits.get("unseen") or () if s not in train)
    commands = []
    for experiment in plan.experiments:
        cfg = compose_job(f"experiment={experiment}", plan.losses[0], plan.overrides)
        if str(cfg.hydra.runtime.choices.data) == choice:
            continue
        crop = bool(cfg.data.frames.get("crop", False))
        for job in sorted(p for p in plan.sweep_dir.glob("*") if _job_of(p, experiment)):
            out = plan.sweep_dir / EVALUATIONS / choice / job.name
            if (out / "results.json").is_file():
                continue
            commands.append([
                sys.executable, "-m", "lossvo.eval", f"ckpt_path={job / 'checkpoints' / 'best.ckpt'}",
                f"data={choice}", *data, f"data.frames.crop={str(crop).lower()}",
                f"data.splits.test=[{test}]", f"data.splits.unseen=[{unseen}]", f"hydra.run.dir={out}",
            ])  # fmt: skip
    return commands


def job_environment(plan: Plan, environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """The jobs' environment: ``environ`` over :data:`KEPT_MEMORY` on a CPU."""
    return {**({} if plan.gpu else KEPT_MEMORY), **environ}


def run(plan: Plan) -> int:
    """The sweeps, :func:`cross_evaluations`, the report (also after a failed job) and the wall time; the
    report's exit status where it fails, else the first failed command's."""
    start, env = time.perf_counter(), job_environment(plan)
    statuses = [subprocess.run(command, env=env).returncode for command in plan.sweep_commands()]
    statuses += [subprocess.run(command, env=env).returncode for command in cross_evaluations(plan)]
    status = next((s for s in statuses if s != 0), 0)
    report = subprocess.run(plan.report_command()).returncode
    emit(f"study: wall time {_hours(time.perf_counter() - start)}")
    return report if report != 0 else status


@one_line_main
def main(argv: list[str] | None = None) -> int:
    """Warn about too few seeds, plan, print the estimate and the commands; unless ``--dry-run``, run them."""
    args = parser().parse_args(argv)
    warning = seed_warning(args.seeds, args.losses)
    if warning:
        print(warning, file=sys.stderr)
    try:
        sweep_dir = sweep_dir_of(args)
        job_gib = checked_jobs(args, sweep_dir)
        plan = plan_study(args, torch.cuda.is_available(), job_gib, sweep_dir)
    except OmegaConfBaseException as e:  # a study's override that does not resolve
        raise UserError(one_line(e)) from None
    emit(gpu_line(plan, job_gib) if plan.gpu else cpu_estimate(plan))
    for command in plan.sweep_commands():
        emit(shlex.join(["python", *command[1:]]))
    if args.dry_run:
        return 0
    return run(plan)


if __name__ == "__main__":
    sys.exit(main())
