"""The sweep's networks on other datasets: the table "trained on X, evaluated on Y", from the results.json
that ``python -m lossvo.eval`` wrote for the sweep's checkpoints under ``SWEEP/evaluations/``, with the
baselines on each such dataset. See docs/report.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import cast

import numpy as np

from lossvo.console import first_line
from lossvo.evaluation import baselines
from lossvo.evaluation.job_folder import MULTI_LAYOUT, DataRecord, JobFolderError, Results, Scores
from lossvo.evaluation.metrics import AlignMode
from lossvo.report.jobs import Job
from lossvo.table_render import Rows

TRAINING_KEYS = ("train_root", "train", "train_layout", "train_keep_every", "train_sources")
"""The fields of a :class:`DataRecord` that say what its network trained on."""
EVALUATIONS = "evaluations"
"""The folder of a sweep that holds evaluations of its checkpoints on other data."""
ACROSS_TITLE = "Across datasets: trained on X, evaluated on Y"
ACROSS_TEXT = (
    "Each configuration's checkpoints evaluated on other datasets (`python -m lossvo.eval ... "
    f"hydra.run.dir=SWEEP/{EVALUATIONS}/...`): mean ± standard deviation over seeds (n) of the APE and RPE "
    "pooled over the evaluated sequences; rows whose two datasets agree are the sweep's own evaluations. "
    "The scale-given RPE scores each predicted step scaled to the ground truth's length (as ORB+E); a "
    "platform whose camera gives metric scale a cue (a car's, at a known height above a road) is read by the "
    "metric RPE, the others by the scale-given one (*translation read as*). On each other dataset the "
    "baselines follow each set of its sequences, computed on those sequences (the mean motion and the flow's "
    "speed fitted on the training split of a network trained on one dataset where one was evaluated, else on "
    "every training sequence of a network trained on several); *rot below zero motion* is how far the mean "
    "rotation RPE lies below zero motion's there."
)
HEADER = ("network", "trained on", "evaluated on", "sequences", "n", "APE trans RMSE (m)",
          "RPE trans RMSE (m)", "RPE trans RMSE, scale given (m)", "RPE rot RMSE (rad)",
          "rot below zero motion", "translation read as")  # fmt: skip


@dataclass(frozen=True)
class Evaluation:
    """One evaluation of a sweep job's checkpoint: the training ``job`` and what the evaluation wrote."""

    job: Job
    results: Results


def dataset_name(layout: str, root: str | None) -> str:
    """A dataset as the table names it: its layout and its folder's name, ``"tum: tum_synthetic"``."""
    return f"{layout}: {Path(root).name if root else '?'}"


def find_evaluations(sweep: Path, jobs: Sequence[Job]) -> tuple[list[Evaluation], list[str]]:
    """The evaluations of ``jobs``' checkpoints under ``sweep/evaluations``, and notes on those unusable."""
    folder = sweep / EVALUATIONS
    by_folder = {job.path.resolve(): job for job in jobs if job.included}
    by_name = {job.path.name: job for job in jobs if job.included}
    found, notes = [], []
    for path in sorted(folder.rglob("results.json")) if folder.is_dir() else []:
        try:
            results = Results.read(path)
        except JobFolderError as e:
            notes.append(str(e))
            continue
        job_folder = Path(results.checkpoint).resolve().parent.parent if results.checkpoint else None
        job = None if job_folder is None else by_folder.get(job_folder)
        if job is None and job_folder is not None and not job_folder.exists():
            job = by_name.get(job_folder.name)
        if job is None:
            notes.append(f"{path}: its checkpoint ({results.checkpoint}) is of no job of this sweep")
            continue
        found.append(Evaluation(job, results))
    return found, notes


def _key(job: Job, results: Results) -> tuple[str, str, str, str]:
    """A row: the configuration, its training data, the evaluated data and sequences."""
    data: DataRecord = results.data
    trained = dataset_name(data.train_layout, data.train_root)
    return job.label, trained, dataset_name(data.layout, data.root), ", ".join(results.overall.sequences)


def _cell(values: list[float]) -> str:
    """``mean ± sample std`` (the mean alone for one value; ``-`` for none)."""
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.4g}"
    return f"{np.mean(values):.4g} ± {np.std(values, ddof=1):.2g}"


def across_rows(
    jobs: Sequence[Job],
    evaluations: Sequence[Evaluation],
    base: dict[tuple[str, str], dict[str, Rmses]] | None = None,
) -> Rows:
    """One row per :func:`_key` over seeds, own evaluations first, each set followed by its baselines."""
    base = base or {}
    runs = [(job, job.included_results) for job in jobs if job.included]
    runs += [(e.job, e.results) for e in evaluations]
    groups: dict[tuple[str, str, str, str], list[Results]] = {}
    for job, results in runs:
        if results.overall.scores is not None:
            groups.setdefault(_key(job, results), []).append(results)
    order = sorted(groups, key=lambda k: (k[2] != k[1], k[2], k[3], k[0]))
    rows: list[list[object]] = []
    for i, key in enumerate(order):
        (label, trained, evaluated, sequences), group = key, groups[key]
        scores = [r.overall.scores for r in group if r.overall.scores is not None]
        here = base.get((evaluated, sequences), {})
        zero = here.get(baselines.ZERO)
        cells, read = _score_cells([Rmses.of(s) for s in scores], zero), read_as(group[0])
        rows.append([label, trained, evaluated, sequences, len(scores), *cells, read])
        last_here = i + 1 == len(order) or order[i + 1][2:] != key[2:]
        for name, pooled in here.items() if last_here else ():
            rows.append([name, "-", evaluated, sequences, "-", *_score_cells([pooled], zero), read])
    return Rows(HEADER, rows)


@dataclass(frozen=True)
class Rmses:
    """A row's APE, RPE, scale-given RPE (None: unrecorded) RMSEs (m) and RPE rotation RMSE (rad)."""

    ape: float
    rpe: float
    rpe_scaled: float | None
    rot: float

    @classmethod
    def of(cls, scores: Scores) -> Rmses:
        scaled = None if scores.rpe_scaled is None else scores.rpe_scaled.trans.rmse
        return cls(scores.ape.trans.rmse, scores.rpe.trans.rmse, scaled, scores.rpe.rot_rad.rmse)


def _score_cells(values: Sequence[Rmses], zero: Rmses | None) -> list[str]:
    """The cells over ``values`` (one a seed) and the rotation's reduction against zero motion's."""
    rot = [v.rot for v in values]
    below = "-" if zero is None else f"{1 - float(np.mean(rot)) / zero.rot:.0%}"
    scaled = [v.rpe_scaled for v in values if v.rpe_scaled is not None]
    return [_cell([v.ape for v in values]), _cell([v.rpe for v in values]), _cell(scaled), _cell(rot), below]


def across_baselines(
    evaluations: Sequence[Evaluation], cache_dir: Path, n_jobs: int
) -> tuple[dict[tuple[str, str], dict[str, Rmses]], list[str]]:
    """{(evaluated dataset, sequences): {baseline: pooled RMSEs}} where the evaluated data is not the
    training data, and a note for each without."""
    by_key: dict[tuple[str, str], list[Results]] = {}
    for e in evaluations:
        _, trained, evaluated, names = _key(e.job, e.results)
        if evaluated != trained and e.results.overall.scores:
            by_key.setdefault((evaluated, names), []).append(e.results)
    single = [e.results.data for e in evaluations if e.results.data.train_layout != MULTI_LAYOUT]
    out, notes = {}, []
    for (evaluated, names), results in sorted(by_key.items()):
        training = baseline_training(results, single)
        if training is None:
            notes.append(
                f"{evaluated} ({names}): no baselines: no network evaluated there has its training recorded"
            )
            continue
        first = results[0]
        data = replace(first.data, **{key: getattr(training, key) for key in TRAINING_KEYS})
        sequences = first.overall.sequences
        try:
            align = cast("AlignMode", first.align)
            computed = baselines.compute_baselines(data, sequences, cache_dir, align, first.delta, n_jobs)
        except Exception as e:  # missing data, a damaged sequence: the table goes on without them
            notes.append(f"{evaluated} ({names}): baselines skipped: {type(e).__name__}: {first_line(e)}")
            continue
        out[(evaluated, names)] = {
            name: pooled_rmses([computed[s][name] for s in sequences], first.delta)
            for name in baselines.NAMES
        }
    return out, notes


def baseline_training(results: Sequence[Results], single: Sequence[DataRecord]) -> DataRecord | None:
    """The training split for the baselines of ``results`` (of one dataset): the first there of a network
    trained on one dataset, else the first such anywhere (``single``), else the first there of a network
    trained on several with their sources recorded; None without."""
    own = [r.data for r in results if r.data.train_layout != MULTI_LAYOUT]
    several = [r.data for r in results if r.data.train_layout == MULTI_LAYOUT and r.data.train_sources]
    return next(iter([*own, *single, *several]), None)


def pooled_rmses(results: Sequence[baselines.BaselineResult], delta: int) -> Rmses:
    """One baseline's RMSEs pooled over sequences as a network's ``overall`` is, weighting each sequence's
    RMSE² by its count of poses (APE) or of pose pairs ``delta`` apart (RPE)."""
    frames = np.array([len(r.trajectory) for r in results], dtype=np.float64)
    pairs = np.maximum(frames - delta, 0)
    each = [Rmses.of(r.scores) for r in results]

    def rmse(values: Sequence[float | None], counts: np.ndarray) -> float:
        squares = np.square(np.asarray(values, dtype=np.float64)) * counts
        return float(np.sqrt(np.sum(squares) / max(float(np.sum(counts)), 1.0)))

    scaled = [v.rpe_scaled for v in each]
    return Rmses(
        ape=rmse([v.ape for v in each], frames),
        rpe=rmse([v.rpe for v in each], pairs),
        rpe_scaled=None if None in scaled else rmse(scaled, pairs),
        rot=rmse([v.rot for v in each], pairs),
    )


def read_as(results: Results) -> str:
    """Which translation RPE reads an evaluation (``metric`` where every platform gives scale a cue)."""
    flags = {s.metric_scale for s in results.sequences.values() if s.scores is not None}
    if flags == {True}:
        return "metric"
    if flags == {False}:
        return "scale given"
    return "-" if flags <= {None} else "per sequence"
