"""Convergence of each configuration: per seed, the first epoch within 10 % of the best validation score
(``tables/convergence.csv`` and the *Convergence* section of report.md)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from lossvo import table_render
from lossvo.report import statistics
from lossvo.report.configurations import SCORE, job_selection
from lossvo.report.jobs import Job
from lossvo.report.tables import NETWORK, Cell, Column, with_architecture
from lossvo.table_render import Rows


@dataclass
class Convergence:
    """A configuration's convergence, per seed: the column used, the first epoch (1-based) within
    :data:`~lossvo.report.statistics.CONVERGENCE_TOLERANCE` of the best (None without), epochs logged."""

    label: str
    replicates: list[str]
    metrics: list[str]
    epochs: list[int | None]
    logged: list[int]
    architecture: str | None = None

    def cell(self) -> Cell:
        return Cell.of(self.epochs)

    @property
    def seed_epochs(self) -> dict[str, int]:
        """``{replicate: epoch}`` of the seeds with a convergence epoch."""
        return {r: e for r, e in zip(self.replicates, self.epochs, strict=True) if e is not None}


def job_convergence(job: Job) -> tuple[str, int | None, int]:
    """(column, convergence epoch (1-based) or None, epochs logged) of one job, on ``val/score`` where
    logged, else on its selection monitor."""
    column, mode = SCORE, "min"
    if job.curves is None or SCORE not in job.curves.series:
        selection = job_selection(job.config)
        column, mode = selection.monitor, selection.mode
    if job.curves is None or column not in job.curves.series:
        return column, None, 0
    epochs, values = job.curves.series[column]
    epoch = statistics.convergence_epoch(epochs, values, mode=mode)
    return column, (epoch + 1 if epoch is not None else None), len(epochs)


def convergence(columns: Sequence[Column]) -> list[Convergence]:
    """One :class:`Convergence` per network column, replicates in the column's order."""
    out = []
    for c in (c for c in columns if c.kind == NETWORK):
        per_job = [job_convergence(j) for j in c.jobs]
        metrics = [m for m, _, _ in per_job]
        epochs = [e for _, e, _ in per_job]
        logged = [n for _, _, n in per_job]
        out.append(Convergence(c.label, list(c.replicates), metrics, epochs, logged, c.architecture))
    return out


def epoch_text(cell: Cell) -> str:
    """Epochs as ``"mean ± std"`` with one decimal (``"n/a"`` without any)."""
    if cell.n == 0:
        return "n/a"
    return f"{cell.mean:.1f}" + (f" ± {cell.std:.1f}" if cell.n > 1 else "")


CONVERGENCE_TEXT = (
    f"The first epoch (counted from 1, as in the curves; metrics.csv counts from 0) at which the "
    f"validation score comes within {statistics.CONVERGENCE_TOLERANCE:.0%} of its best over the run "
    f"(value <= best × {1 + statistics.CONVERGENCE_TOLERANCE:g} for a min metric), mean ± sample std over "
    f"seeds. The score is the loss-independent `{SCORE}`, the same for every loss."
)


def convergence_markdown(items: Sequence[Convergence], by_architecture: bool = False) -> str:
    """The rule, a note on curves measured on another metric, and the table."""
    lines = [CONVERGENCE_TEXT]
    fallback = sorted({m for c in items for m in c.metrics if m != SCORE})
    if fallback:
        lines += [
            "",
            f"*Note:* `{SCORE}` is not in every metrics.csv: those jobs are measured on their selection "
            f"monitor ({', '.join(f'`{m}`' for m in fallback)}), which is not on one scale across losses.",
        ]
    return "\n".join([*lines, "", table_render.markdown(convergence_rows(items, by_architecture))])


def convergence_rows(items: Sequence[Convergence], by_architecture: bool = False) -> Rows:
    """The *Convergence* table, a row per configuration."""
    header = ["configuration", "metric", "seeds with a curve", "epoch (mean ± std)", "per seed",
              "epochs logged"]  # fmt: skip
    rows: list[list[object]] = []
    for c in items:
        pairs = zip(c.replicates, c.epochs, strict=True)
        per_seed = ", ".join(f"{r}: {e if e is not None else 'n/a'}" for r, e in pairs)
        logged = ", ".join(map(str, sorted(set(c.logged))))
        metrics = ", ".join(sorted(set(c.metrics)))
        rows.append([c.architecture, c.label, metrics, c.cell().n, epoch_text(c.cell()), per_seed, logged])
    return with_architecture(header, rows, by_architecture)


def convergence_csv_rows(items: Sequence[Convergence], by_architecture: bool = False) -> Rows:
    """``tables/convergence.csv``: a row per configuration and seed, then its ``mean`` and ``std`` rows."""
    rows: list[list[object]] = []
    for c in items:
        for r, m, e, n in zip(c.replicates, c.metrics, c.epochs, c.logged, strict=True):
            rows.append([c.architecture, c.label, r, m, "" if e is None else e, n])
        metric, (mean, std, _) = ",".join(sorted(set(c.metrics))), c.cell().csv()
        rows += [[c.architecture, c.label, part, metric, x, ""] for part, x in (("mean", mean), ("std", std))]
    header = ["configuration", "seed", "metric", "epoch", "epochs_logged"]
    return with_architecture(header, rows, by_architecture)
