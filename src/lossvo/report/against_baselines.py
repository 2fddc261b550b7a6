"""The baselines in a sweep report (:func:`run_baselines`, computed on the data each sequence's jobs
recorded, :func:`data_groups`), their section, and each job against them on the validation sequences
(:func:`learning_markdown`) and the unseen-motion ones (:func:`unseen_markdown`). See docs/report.md.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from lossvo import table_render
from lossvo.console import first_line
from lossvo.evaluation import baselines
from lossvo.evaluation.job_folder import Scores
from lossvo.evaluation.metrics import AlignMode
from lossvo.report.jobs import (
    RPE_ROT,
    RPE_TRANS,
    Job,
    check_on_disk,
    config_sequences,
    finite_number,
    metric_value,
)
from lossvo.report.tables import BASELINE, UNKNOWN_ARCHITECTURE, Column, fmt, with_architecture

UNSEEN_KEY = "data.splits.unseen"
UNSEEN_ROTATION_BAR = 0.30
"""Fraction by which a job's RPE rotation RMSE must lie below zero motion's on an unseen-motion sequence."""
LEARNING_METRICS = (("RPE trans", RPE_TRANS), ("RPE rot", RPE_ROT))


@dataclass
class BaselineRun:
    """The baselines of a report: columns, trajectories (N, 4, 4), ORB failures, frame counts and notes."""

    columns: list[Column] = field(default_factory=list)
    trajectories: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    failures: dict[str, int] = field(default_factory=dict)
    frames: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    cached: int = 0


def evaluation_settings(jobs: Sequence[Job]) -> tuple[str, int, list[str]]:
    """(align, delta) of the first job's results.json, and a note if the jobs differ."""
    settings = [(j.included_results.align, j.included_results.delta) for j in jobs]
    differ = f"jobs differ in align/delta {sorted(set(settings))}: baselines use {settings[0]}"
    return *settings[0], [differ] if len(set(settings)) > 1 else []


def data_groups(
    jobs: Sequence[Job], sequences: Sequence[str]
) -> tuple[list[tuple[Job, list[str]]], list[str]]:
    """The included ``jobs`` grouped by their data (:meth:`DataRecord.identity`): each group's first job
    with the ``sequences`` its group evaluated and no earlier group did; a note naming those shared."""
    groups: dict[str, tuple[Job, set[str]]] = {}
    for job in jobs:
        key = json.dumps(job.included_results.data.identity(), sort_keys=True)
        groups.setdefault(key, (job, set()))[1].update(job.included_results.sequences)
    taken: set[str] = set()
    shared: set[str] = set()
    result = []
    for first, evaluated in groups.values():
        shared |= evaluated & taken
        result.append((first, [s for s in sequences if s in evaluated and s not in taken]))
        taken |= evaluated
    note = (
        f"jobs of different data evaluated {', '.join(sorted(shared))}: their baselines use the first one's"
    )
    return [(job, own) for job, own in result if own], [note] if shared else []


def run_baselines(jobs: Sequence[Job], sequences: Sequence[str], cache_dir: Path, n_jobs: int) -> BaselineRun:
    """Baselines on ``sequences``, each on its jobs' data; a group's failure is a note."""
    run = BaselineRun()
    start = time.perf_counter()
    align, delta, run.notes = evaluation_settings(jobs)
    mode = cast("AlignMode", align)  # results.json's text; metrics.align rejects an unknown mode
    groups, notes = data_groups(jobs, sequences)
    run.notes += notes
    results: dict[str, dict[str, baselines.BaselineResult]] = {}
    for job, own in groups:
        try:
            check_on_disk(job.included_results.data, job)
            results |= baselines.compute_baselines(
                job.included_results.data, own, cache_dir, mode, delta, n_jobs
            )
        except Exception as e:  # missing data, a damaged sequence: the report goes on without these baselines
            where = "" if len(groups) == 1 else f" ({job.path.name}'s data)"
            run.notes.append(f"baselines skipped{where}: {type(e).__name__}: {first_line(e)}")
    done = [s for s in sequences if s in results]
    for name in baselines.NAMES if results else ():
        per_sequence = {s: results[s][name].scores for s in done}
        run.columns.append(Column(name, BASELINE, ["deterministic"], [per_sequence]))
    for s in done:
        run.trajectories[s] = {name: results[s][name].trajectory for name in baselines.NAMES}
        run.failures[s] = results[s][baselines.ORB].failures
        run.frames[s] = len(results[s][baselines.ZERO].trajectory)
    run.cached = sum(results[s][baselines.ZERO].cached for s in done)
    run.seconds = time.perf_counter() - start
    return run


BASELINES_TEXT = [
    "Computed on the same sequences, integrated from the first ground-truth pose and scored with the "
    "same alignment and RPE delta as the jobs' results.json (`lossvo.evaluation.baselines`), on the dataset "
    "and training split that results.json records:",
    "",
    "- **zero motion**: identity relative poses (the camera stands still);",
    "- **mean motion (train)**: the training split's mean relative pose (mean translation, chordal mean "
    "rotation) at every step;",
    "- **ORB+E (GT scale)**: ORB features, `cv2.findEssentialMat` (RANSAC, OpenCV's USAC) and "
    "`cv2.recoverPose` with the dataset's K (keypoints undistorted where the frames are distorted); "
    "each step's translation is scaled to the ground-truth "
    "step length (monocular VO has no scale: this is an optimistic baseline). A pair whose matches do "
    "not move is a step straight ahead; a pair with too few matches or inliers takes the previous "
    "pair's motion (counted below as a failure);",
    "- **own mean motion (oracle)**: the sequence's own mean relative pose (from its ground truth) at "
    "every step: it knows the sequence's average motion, so a network that learned only an average "
    "motion cannot beat it;",
    "- **flow yaw + road speed (one line)**: DIS optical flow between consecutive frames; the yaw is "
    "atan(-median horizontal flow of the upper half / fx), the step straight ahead with a length of one "
    "constant (least squares on the training split's step lengths) times the median vertical flow of the "
    "road just ahead; no pitch or roll. The floor a network that reads the same flow must clear.",
]


def baselines_markdown(run: BaselineRun, enabled: bool) -> str:
    """The *Baselines* section."""
    if not enabled:
        return "Baselines were not computed (`--no-baselines`)."
    lines = list(BASELINES_TEXT)
    if run.failures:
        total = sum(run.failures.values())
        pairs = sum(n - 1 for n in run.frames.values())
        per = ", ".join(f"{s}: {f}" for s, f in run.failures.items() if f)
        lines += [
            "",
            f"ORB+E failed (fell back) on {total} of {pairs} frame pairs" + (f" ({per})." if per else "."),
        ]
    if run.columns:
        lines += [
            "",
            f"Baselines took {run.seconds:.1f} s ({run.cached} of {len(run.frames)} sequences from "
            "the report's `cache/`, keyed by the recorded data and the sequence).",
        ]
    lines += [f"\n*Note:* {note}" for note in run.notes]
    return "\n".join(lines)


def reduction(value: object, reference: object) -> float | None:
    """``1 - value / reference`` (the fraction by which a network beats a baseline), or None."""
    value, reference = finite_number(value), finite_number(reference)
    if value is None or reference is None or reference <= 0:
        return None
    return 1.0 - value / reference


def _below(value: Scores | None, baseline: Scores | None, path: Sequence[str]) -> str:
    """How far below ``baseline``'s a value at ``path`` lies, as text (``"12 %"``)."""
    r = reduction(metric_value(value, path), metric_value(baseline, path))
    return "–" if r is None else f"{100 * r:.0f} %"


def _baseline(base: BaselineRun, name: str) -> Column | None:
    return next((c for c in base.columns if c.label == name), None)


def learning_markdown(networks: Sequence[Column], base: BaselineRun, by_architecture: bool = False) -> str:
    """Per job and validation sequence, how far below the mean-motion baseline its RPE lies."""
    mean_motion = _baseline(base, baselines.MEAN)
    sequences = config_sequences((j for c in networks for j in c.jobs), "data.splits.val")
    if mean_motion is None or not sequences:
        return "No mean-motion baseline or no validation sequence: nothing to compare."
    header = ["configuration", "seed"] + [f"{s} {name}" for s in sequences for name, _ in LEARNING_METRICS]
    rows: list[list[object]] = []
    for column in networks:
        for job, results in zip(column.jobs, column.results, strict=True):
            mean = mean_motion.results[0]
            cells = [_below(results.get(s), mean.get(s), p) for s in sequences for _, p in LEARNING_METRICS]
            rows.append([column.architecture, column.label, str(job.seed), *cells])
    text = (
        "How far each job's RPE RMSE lies below the mean-motion baseline's on the validation sequences "
        "(1 − network / baseline; negative: worse than predicting the training set's mean motion)."
    )
    return "\n".join([text, "", table_render.markdown(with_architecture(header, rows, by_architecture))])


UNSEEN_HEADER = ("RPE rot [rad]", "vs zero motion", "RPE trans [m]", "vs own mean motion", "both met")


def unseen_cells(entry: Scores | None, zero: Scores | None, own: Scores | None) -> tuple[list[str], bool]:
    """A job's :data:`UNSEEN_HEADER` cells on one sequence, and whether both criteria are met."""
    rot, trans = (finite_number(metric_value(entry, path)) for path in (RPE_ROT, RPE_TRANS))
    rot_down = reduction(rot, metric_value(zero, RPE_ROT))
    trans_down = reduction(trans, metric_value(own, RPE_TRANS))
    met = (
        rot_down is not None and rot_down >= UNSEEN_ROTATION_BAR and trans_down is not None and trans_down > 0
    )
    rmse = ["–" if v is None else fmt(v) for v in (rot, trans)]
    down = ["–" if r is None else f"{100 * r:.1f} %" for r in (rot_down, trans_down)]
    return [rmse[0], down[0], rmse[1], down[1], "yes" if met else "no"], met


UNSEEN_TEXT = (
    f"On the sequences of route families never used for training (`{UNSEEN_KEY}`): each job's RPE "
    "rotation RMSE against zero motion's and its RPE translation RMSE against the sequence's own mean "
    "motion (the oracle), as 1 − network / baseline. Both are met when the rotation lies at least "
    f"{100 * UNSEEN_ROTATION_BAR:.0f} % below zero motion's and the translation below the oracle's "
    "(a reduction above 0); a missing value meets neither."
)


def unseen_markdown(
    networks: Sequence[Column], base: BaselineRun, unseen: Sequence[str], by_architecture: bool = False
) -> str:
    """Per job and unseen-motion sequence :func:`unseen_cells`, and how many jobs meet both on every one."""
    zero, own = _baseline(base, baselines.ZERO), _baseline(base, baselines.OWN)
    if zero is None or own is None:
        return "No zero-motion or own-mean-motion baseline: nothing to compare."
    rows: list[list[object]] = []
    passed: dict[str, list[bool]] = {}
    for column in networks:
        for job, results in zip(column.jobs, column.results, strict=True):
            every = True
            for s in unseen:
                cells, ok = unseen_cells(results.get(s), zero.results[0].get(s), own.results[0].get(s))
                rows.append([column.architecture, column.label, job.seed, s, *cells])
                every &= ok
            passed.setdefault(column.architecture or UNKNOWN_ARCHITECTURE, []).append(every)
    table = with_architecture(["configuration", "seed", "sequence", *UNSEEN_HEADER], rows, by_architecture)
    if by_architecture:
        counts = "; ".join(f"{a}: {sum(met)} of {len(met)}" for a, met in passed.items())
        summary = f"Jobs that meet both on every unseen sequence, per architecture: {counts}."
    else:
        met = [m for ms in passed.values() for m in ms]
        summary = f"{sum(met)} of {len(met)} jobs meet both on every unseen sequence."
    return "\n".join([UNSEEN_TEXT, "", table_render.markdown(table), "", summary])
