"""The sweep's networks on other datasets: the table "trained on X, evaluated on Y".

An evaluation is a folder holding the ``results.json`` that ``python -m lossvo.eval`` wrote for a checkpoint
of one of the sweep's jobs, found under ``SWEEP/evaluations/`` (any depth), for example::

    python -m lossvo.eval ckpt_path=SWEEP/3_loss-quat+seed-0/checkpoints/best.ckpt data=tum \\
        data.sources.tum.root=/data/tum hydra.run.dir=SWEEP/evaluations/tum/3

Each row pools one configuration (the job's label, seeds apart) on one evaluated dataset: the mean ± standard
deviation over its seeds (n) of the pooled APE and RPE of every evaluated sequence. The sweep's own
evaluations (on the data each job trained with) are the rows where both datasets agree.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lossvo.evaluation.results import DataRecord, Results, ResultsError
from lossvo.report.jobs import Job
from lossvo.table_render import Rows

EVALUATIONS = "evaluations"
"""The folder of a sweep that holds evaluations of its checkpoints on other data."""
ACROSS_TITLE = "Across datasets: trained on X, evaluated on Y"
ACROSS_TEXT = (
    "Each configuration's checkpoints evaluated on other datasets (`python -m lossvo.eval ... "
    f"hydra.run.dir=SWEEP/{EVALUATIONS}/...`): mean ± standard deviation over seeds (n) of the APE and RPE "
    "pooled over the evaluated sequences; rows whose two datasets agree are the sweep's own evaluations."
)
HEADER = (
    "network",
    "trained on",
    "evaluated on",
    "sequences",
    "n",
    "APE trans RMSE (m)",
    "RPE trans RMSE (m)",
    "RPE rot RMSE (rad)",
)


@dataclass(frozen=True)
class Evaluation:
    """One evaluation of a sweep job's checkpoint: the training ``job`` and what the evaluation wrote."""

    job: Job
    results: Results


def dataset_name(layout: str, root: str | None) -> str:
    """A dataset as the table names it: its layout and its folder's name, ``"tum: tum_synthetic"``."""
    return f"{layout}: {Path(root).name if root else '?'}"


def find_evaluations(sweep: Path, jobs: Sequence[Job]) -> tuple[list[Evaluation], list[str]]:
    """The evaluations under ``sweep/evaluations`` of checkpoints of ``jobs``, and a note for each
    results.json that could not be used (unreadable, or of a checkpoint of no job of this sweep)."""
    folder = sweep / EVALUATIONS
    by_folder = {job.path.resolve(): job for job in jobs if job.included}
    found, notes = [], []
    for path in sorted(folder.rglob("results.json")) if folder.is_dir() else []:
        try:
            results = Results.read(path)
        except ResultsError as e:
            notes.append(str(e))
            continue
        checkpoint = Path(results.checkpoint) if results.checkpoint else None
        job = by_folder.get(checkpoint.resolve().parent.parent) if checkpoint else None
        if job is None:
            notes.append(f"{path}: its checkpoint ({results.checkpoint}) is of no job of this sweep")
            continue
        found.append(Evaluation(job, results))
    return found, notes


def _key(job: Job, results: Results) -> tuple[str, str, str]:
    data: DataRecord = results.data
    return job.label, dataset_name(data.train_layout, data.train_root), dataset_name(data.layout, data.root)


def _cell(values: list[float]) -> str:
    """``mean ± std`` (sample standard deviation; the mean alone for one value)."""
    if len(values) == 1:
        return f"{values[0]:.4g}"
    return f"{np.mean(values):.4g} ± {np.std(values, ddof=1):.2g}"


def across_rows(jobs: Sequence[Job], evaluations: Sequence[Evaluation]) -> Rows:
    """The table: one row per (configuration, trained on, evaluated on), the sweep's own evaluations first,
    then the other datasets in name order; cells over seeds (:func:`_cell`)."""
    runs = [(job, job.included_results) for job in jobs if job.included]
    runs += [(e.job, e.results) for e in evaluations]
    groups: dict[tuple[str, str, str], list[Results]] = {}
    for job, results in runs:
        if results.overall.scores is not None:
            groups.setdefault(_key(job, results), []).append(results)
    order = sorted(groups, key=lambda k: (k[2] != k[1], k[2], k[0]))
    rows = []
    for label, trained, evaluated in order:
        scores = [r.overall.scores for r in groups[label, trained, evaluated] if r.overall.scores is not None]
        sequences = ", ".join(groups[label, trained, evaluated][0].overall.sequences)
        rows.append(
            [
                label,
                trained,
                evaluated,
                sequences,
                len(scores),
                _cell([s.ape.trans.rmse for s in scores]),
                _cell([s.rpe.trans.rmse for s in scores]),
                _cell([s.rpe.rot_rad.rmse for s in scores]),
            ]
        )
    return Rows(HEADER, rows)
