"""The report of a sweep: ``report.md``, ``tables/`` and ``figures/`` (:func:`make_report`), every file
written atomically; per architecture where the sweep varies it (docs/report.md)."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from lossvo import table_render
from lossvo.atomic import write_text_atomic
from lossvo.evaluation.results import file_stem
from lossvo.report import across_datasets, against_baselines, architectures, claims, comparison
from lossvo.report.against_baselines import BaselineRun, run_baselines
from lossvo.report.claims import CLAIMED_LOSS, Claim
from lossvo.report.comparison import Comparison
from lossvo.report.configurations import (
    architecture_file_name,
    architecture_groups,
    configuration_rows,
    label_jobs,
    network_columns,
    selection_warning,
    varies_architecture,
)
from lossvo.report.convergence import Convergence, convergence, convergence_csv_rows, convergence_markdown
from lossvo.report.figures import plot_ape_bars, plot_curves, plot_forest, plot_trajectories
from lossvo.report.frame import results_frame
from lossvo.report.jobs import Job, code_versions_note, ground_truth, job_dirs, load_job, machines_note
from lossvo.report.speed import SPEED_TEXT, SPEED_TITLE, speed_rows
from lossvo.report.statistics import ALPHA, MARGIN
from lossvo.report.tables import (
    TABLES,
    Column,
    Table,
    TableSpec,
    build_table,
    evaluated_sequences,
    table_csv,
    table_latex,
    table_rows,
    with_architecture,
)
from lossvo.table_render import Rows

log = logging.getLogger("lossvo")

UNSEEN_NOTE = "unseen motion"
TABLE_FILES = ("pairwise.csv", "configurations.csv", "convergence.csv", "claims.csv")
ARCHITECTURE_FILES = ("rankings.csv", "interaction.csv")


def build_tables(
    networks: Sequence[Column], baselines: Sequence[Column], sequences: Sequence[str], notes: dict[str, str]
) -> list[Table]:
    """Tables I-III of the networks beside the baselines (each per architecture where several)."""
    if not networks:
        return []
    frame = results_frame([*networks, *baselines])
    return [
        build_table(_architecture_spec(spec, architecture), [*group, *baselines], sequences, notes, frame)
        for spec in TABLES
        for architecture, group in architecture_groups(networks, varies_architecture(networks)).items()
    ]


def _architecture_spec(spec: TableSpec, architecture: str) -> TableSpec:
    if not architecture:
        return spec
    key = f"{spec.key}_{architecture_file_name(architecture)}"
    return replace(spec, key=key, title=f"{spec.title}, architecture {architecture}")


@dataclass
class Figures:
    """The PNGs written and notes on what they lack."""

    paths: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass
class Contents:
    """Everything report.md shows: besides the tables, the network columns' convergence and claims, the
    sequences of unseen motion and, across architectures, whether they rank the losses alike."""

    jobs: list[Job]
    networks: list[Column]
    sequences: list[str]
    unseen: list[str]
    by_architecture: bool
    convergence: list[Convergence]
    claims: list[Claim]
    agreement: architectures.Agreement | None
    base: BaselineRun
    baselines_on: bool
    tables: list[Table] = field(default_factory=list)
    comparisons: list[Comparison] = field(default_factory=list)
    figures: Figures | None = None
    speed: Rows | None = None
    across: Rows | None = None
    across_notes: list[str] = field(default_factory=list)


def jobs_rows(jobs: Sequence[Job], by_architecture: bool = False) -> Rows:
    """Every job: folder, configuration, seed, status, whether it is in the tables (or why not), notes."""
    rows: list[list[object]] = []
    for j in jobs:
        used = "yes" if j.skip is None else f"no: {j.skip}"
        rows.append(
            [j.architecture, f"`{j.path.name}`", j.label or "?", j.seed, j.status, used, "; ".join(j.notes)]
        )
    header = ["job", "configuration", "seed", "status", "in tables", "notes"]
    return with_architecture(header, rows, by_architecture)


def seeds_text(networks: Sequence[Column]) -> str:
    counts = ", ".join(f"{c.label}: n = {len(c.replicates)} ({', '.join(c.replicates)})" for c in networks)
    if any(len(c.replicates) > 1 for c in networks):
        return (
            "Cells are the mean ± the sample standard deviation (ddof = 1) over seeds; bold marks the "
            "lowest mean. The mean row averages each seed over the sequences first, then takes mean ± std "
            f"over seeds. Seeds per configuration: {counts}."
        )
    return (
        f"One seed per configuration ({counts}): no seed-noise estimate is available, so differences "
        "between configurations below cannot be told apart from the run-to-run variation of training."
    )


def figures_markdown(figures: Figures | None, out: Path) -> str:
    if figures is None:
        return "Figures were not drawn (`--no-figures`)."
    if not figures.paths:
        return "No figures (no job with curves or results)."
    lines = [f"![{p.stem}]({p.relative_to(out).as_posix()})" for p in figures.paths]
    return "\n\n".join([*lines, *(f"*Note:* {note}" for note in figures.notes)])


def section(title: str, *blocks: str) -> list[str]:
    """A ``## title`` section of report.md, its blocks separated by blank lines."""
    return ["", f"## {title}", *(line for block in blocks for line in ("", block))]


def header_lines(sweep: Path, c: Contents) -> list[str]:
    """The title, the job count and the warnings."""
    included = sum(j.included for j in c.jobs)
    lines = [
        f"# Sweep report: `{sweep}`",
        "",
        f"Generated {time.strftime('%Y-%m-%d %H:%M:%S')} by `python -m lossvo.report`. "
        f"{len(c.jobs)} job(s): {included} included, {len(c.jobs) - included} skipped (see *Jobs*).",
    ]
    if c.by_architecture:
        groups = architecture_groups(c.networks)
        names = ", ".join(f"`{a}` ({sum(len(c.jobs) for c in g)} jobs)" for a, g in groups.items())
        lines += ["", ARCHITECTURES_TEXT.format(names=names)]
    warnings = [selection_warning(c.networks), code_versions_note(c.jobs), machines_note(c.jobs)]
    return lines + [x for w in warnings if w for x in ("", w)]


ARCHITECTURES_TEXT = (
    "This sweep varies the architecture (the `model` config group's choice, else the network's class): "
    "{names}. Tables I-III, the curves and the APE bars are given per architecture, the tables of "
    "configurations and jobs have an `architecture` column, pairs are compared and the study's claims "
    "tested within an architecture, and *Architectures* asks whether the architectures rank the losses "
    "alike."
)


CONFIGURATIONS_TEXT = (
    "Rotation weight: the small-angle weight of the rotation term relative to the translation "
    "term, k · gain: each loss's rotation term is ≈ gain · θ² for a small rotation error θ (rad), "
    "so a configuration's loss is ≈ |t − t^|² (m²) + k · gain · θ². Under learned weighting it is "
    "gain · exp(s_t − s_r) at the last epoch (mean ± std over seeds). Selected by: the metric "
    "that chose each job's best checkpoint."
)


def tables_lines(c: Contents) -> list[str]:
    """What the tables show, then Tables I-III."""
    included = [j for j in c.jobs if j.included]
    if not included:
        return ["", "No job has usable results yet: no tables."]
    align, delta, _ = against_baselines.evaluation_settings(included)
    unseen = (
        f" Rows marked ({UNSEEN_NOTE}) are sequences of route families never used for training "
        f"(`{against_baselines.UNSEEN_KEY}`): {', '.join(c.unseen)}."
        if c.unseen
        else ""
    )
    lines = [
        "",
        f"Test sequences: {', '.join(c.sequences)}. APE alignment: `{align}`; RPE delta: {delta} "
        "frame(s) (as in the jobs' results.json). Columns are named by the overrides that differ "
        "between jobs; **bold**: the lowest value of the row over all columns, baselines "
        "included, so a winning baseline shows."
        + unseen
        + (PER_ARCHITECTURE_TEXT if c.by_architecture else ""),
        "",
        seeds_text(c.networks),
    ]
    for table in c.tables:
        lines += section(table.spec.title, table_render.markdown(table_rows(table)))
        if table.mean_over != table.rows[:-1]:
            mean_over = ", ".join(table.mean_over) or "none"
            lines += ["", f"Mean over the sequences with a value in every column: {mean_over}."]
    return lines


PER_ARCHITECTURE_TEXT = (
    " Each table is given per architecture: that architecture's configurations beside the baselines, bold "
    "over that table's columns."
)
PAIRWISE_TEXT = (
    "Seeds are the unit: a seed's value is its mean over the evaluated sequences that both configurations "
    "have on every paired seed, and A and B are paired by seed (the sequences of one seed share one "
    "trained network, so (seed, sequence) cells are not independent). Two-sided exact Wilcoxon "
    "signed-rank test (`scipy.stats.wilcoxon`) on the per-seed differences A − B, or, with ties or zeros "
    "among them, the exact sign-flip permutation test of their mean; Holm's correction over the pairs of "
    f"one metric; *distinguishable* means Holm p < {ALPHA}. With n seeds no exact test gives p below 2/2^n, "
    "and Holm multiplies the smallest p by the number of pairs m: where m · 2/2^n ≥ "
    f"{ALPHA} the row says the seeds cannot decide (one pair needs 6 seeds)."
)
PAIRWISE_BY_ARCHITECTURE_TEXT = (
    " Pairs of one architecture (the architectures are compared in *Architectures*)."
)


def baseline_lines(c: Contents) -> list[str]:
    """The *Baselines* section, each job against the mean motion and on unseen motion."""
    lines = section("Baselines", against_baselines.baselines_markdown(c.base, c.baselines_on))
    if not (c.baselines_on and any(j.included for j in c.jobs)):
        return lines
    learning = against_baselines.learning_markdown(c.networks, c.base, c.by_architecture)
    lines += section("Against the mean motion, per job", learning)
    if c.unseen:
        unseen = against_baselines.unseen_markdown(c.networks, c.base, c.unseen, c.by_architecture)
        lines += section("Unseen motion", unseen)
    return lines


DAMAGED_CURVES_TEXT = (
    "Jobs whose metrics.csv is damaged stay in the tables (their results.json is intact) and "
    "lose only their loss curves."
)


def render_report(sweep: Path, out: Path, c: Contents) -> str:
    """The text of report.md (``c.figures`` None: not drawn)."""
    by = c.by_architecture
    lines = header_lines(sweep, c)
    if c.networks:
        configurations = table_render.markdown(configuration_rows(c.networks, by))
        lines += section("Configurations", CONFIGURATIONS_TEXT, configurations)
    lines += tables_lines(c)
    pairwise = "Fewer than two configurations with results: nothing to compare."
    if c.comparisons:
        table = table_render.markdown(comparison.comparison_rows(c.comparisons, by))
        pairwise = PAIRWISE_TEXT + (PAIRWISE_BY_ARCHITECTURE_TEXT if by else "") + "\n\n" + table
    lines += section("Pairwise comparison", pairwise)
    if c.convergence:
        lines += section("Convergence", convergence_markdown(c.convergence, by))
    lines += baseline_lines(c)
    lines += section("Jobs", table_render.markdown(jobs_rows(c.jobs, by)), DAMAGED_CURVES_TEXT)
    files = [f"`tables/{t.spec.key}.{ext}`" for t in c.tables for ext in ("csv", "tex")]
    files += [f"`tables/{name}`" for name in (*TABLE_FILES, *(ARCHITECTURE_FILES if by else ()))]
    lines += section("Files", f"Tables as CSV and LaTeX (booktabs): {', '.join(files)}.")
    lines += section("Figures", figures_markdown(c.figures, out))
    if c.agreement is not None:
        agreement = architectures.agreement_markdown(c.agreement)
        lines += section("Architectures: does the loss ranking agree?", agreement)
    if c.speed is not None and c.speed.rows:
        lines += section(SPEED_TITLE, SPEED_TEXT, table_render.markdown(c.speed))
    unused = ["", *(f"- {note}" for note in c.across_notes)] if c.across_notes else []
    if c.across is not None and any(row[1] != row[2] for row in c.across.rows):
        across = table_render.markdown(c.across)
        lines += section(across_datasets.ACROSS_TITLE, across_datasets.ACROSS_TEXT, across)
    lines += unused
    lines += section("The study's claims", claims.claims_markdown(c.claims, by))
    return "\n".join(lines) + "\n"


def write_tables(c: Contents, folder: Path) -> None:
    """Tables I-III as CSV and LaTeX, :data:`TABLE_FILES`, :data:`ARCHITECTURE_FILES`, speed and across
    datasets (where measured) into ``folder``."""
    for table in c.tables:
        write_text_atomic(folder / f"{table.spec.key}.csv", table_csv(table))
        write_text_atomic(folder / f"{table.spec.key}.tex", table_latex(table))
    by = c.by_architecture
    files = {
        "pairwise.csv": comparison.comparison_csv_rows(c.comparisons, by),
        "configurations.csv": configuration_rows(c.networks, by, csv=True),
        "convergence.csv": convergence_csv_rows(c.convergence, by),
        "claims.csv": claims.claims_csv_rows(c.claims, by),
        "speed.csv": c.speed,
        "across_datasets.csv": c.across,
    }
    if c.agreement is not None:
        files["rankings.csv"] = architectures.rankings_csv_rows(c.agreement)
        files["interaction.csv"] = architectures.interaction_csv_rows(c.agreement)
    for name, content in files.items():
        if content is not None:
            write_text_atomic(folder / name, table_render.csv_text(content))


def write_figures(c: Contents, folder: Path, gt: dict[str, np.ndarray], missing: dict[str, str]) -> Figures:
    """Every figure, with the ground truth ``gt`` or the reason it is ``missing`` per sequence
    (:func:`lossvo.report.jobs.ground_truth`); the forest plot of the claims."""
    figures = Figures()
    groups = architecture_groups(c.networks, c.by_architecture).items()
    for (architecture, group), table in zip(groups, c.tables, strict=False):  # Table I's first
        suffix = f"_{architecture_file_name(architecture)}" if architecture else ""
        if group and plot_curves(group, folder / f"curves{suffix}.png"):
            figures.paths.append(folder / f"curves{suffix}.png")
        if table.columns:
            plot_ape_bars(table, folder / f"ape_trans_rmse{suffix}.png")
            figures.paths.append(folder / f"ape_trans_rmse{suffix}.png")
    if plot_forest(c.claims, c.networks, folder / "forest.png"):
        figures.paths.append(folder / "forest.png")
    if missing:  # one note, the sequences grouped by reason
        reasons = (
            f"{', '.join(s for s in missing if missing[s] == r)}: {r}"
            for r in dict.fromkeys(missing.values())
        )
        figures.notes.append(f"trajectory figures without ground truth ({'; '.join(reasons)}).")
    for s in c.sequences:
        extra = {k: v for k, v in c.base.trajectories.get(s, {}).items() if not k.startswith("zero")}
        path = folder / f"trajectory_{file_stem(s)}.png"
        plot_trajectories(s, c.networks, gt.get(s), extra, path)
        figures.paths.append(path)
    return figures


def make_report(
    sweep: Path,
    out: Path | None = None,
    with_baselines: bool = True,
    with_figures: bool = True,
    n_jobs: int | None = None,
    margin: float = MARGIN,
    claimed_loss: str = CLAIMED_LOSS,
) -> Path:
    """Write the report of a sweep folder; returns the path of report.md. SweepError if ``sweep`` is not a
    sweep folder."""
    sweep = Path(sweep)
    out = Path(out) if out is not None else sweep / "report"
    jobs = [load_job(p) for p in job_dirs(sweep)]
    for note in (code_versions_note(jobs), machines_note(jobs)):
        if note:
            log.warning("%s", note.replace("**", ""))
    label_jobs([j for j in jobs if j.config is not None])
    networks = network_columns(jobs)
    sequences = evaluated_sequences(networks)
    included = [j for j in jobs if j.included]
    cores = n_jobs or os.cpu_count() or 1
    base = BaselineRun()
    if with_baselines and included and sequences:
        base = run_baselines(included, sequences, out / "cache", cores)
    evaluations, unused = across_datasets.find_evaluations(sweep, included)
    items = convergence(networks)
    marked = {s for c in networks for j in c.jobs for s in j.included_results.unseen()}
    by = varies_architecture(networks)
    found = (claims.claims_by_architecture if by else claims.study_claims)(
        networks, items, sequences, margin, claimed_loss
    )
    agreement = architectures.architecture_agreement(networks, sequences, evaluations) if by else None
    unseen = [s for s in sequences if s in marked]
    c = Contents(jobs, networks, sequences, unseen, by, items, found, agreement, base, with_baselines)
    c.tables = build_tables(networks, base.columns, sequences, dict.fromkeys(unseen, UNSEEN_NOTE))
    c.comparisons = comparison.compare(networks, by)
    gt, missing = ground_truth(included, sequences)
    if with_figures:
        c.figures = write_figures(c, out / "figures", gt, missing)
    c.speed = speed_rows(networks, gt, sequences) if included else None
    c.across_notes = [f"evaluation not used: {note}" for note in unused]
    across_base: dict[tuple[str, str], dict[str, across_datasets.Rmses]] = {}
    if with_baselines and evaluations:
        across_base, base_notes = across_datasets.across_baselines(evaluations, out / "cache", cores)
        c.across_notes += base_notes
    c.across = across_datasets.across_rows(included, evaluations, across_base) if evaluations else None
    write_tables(c, out / "tables")
    write_text_atomic(out / "report.md", render_report(sweep, out, c))
    return out / "report.md"
