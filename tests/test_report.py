"""The sweep report on a real (tiny) sweep: tables equal the jobs' results.json, bold marks the minimum,
mean ± std over seeds, baselines equal an independent computation (evo), damaged jobs are listed, bad
input; rotation weights and selection metrics from the job configs, convergence from metrics.csv, the
claims; the unseen-motion marks and section on hand-written job folders; baselines and ground truth from
the data that hand-written results.json record (no datamodule), and one note when it is gone; the
results.json contract (round trip, one line naming the file for each bad file, a sweep with an unreadable
one); the package's import graph.

The session's one Hydra multirun (2 losses x 2 seeds on the tiny KITTI-layout dataset, ``study_sweep`` in
tests/conftest.py) is read by every test, or a copy of it.
"""

from __future__ import annotations

import ast
import csv
import json
import re
import shutil
import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PosePath3D
from scipy.stats import ttest_1samp, wilcoxon

from conftest import STUDY_LOSSES, STUDY_SEEDS, STUDY_SEQUENCES
from lossvo.console import UserError
from lossvo.evaluation.job_folder import (
    SCHEMA_VERSION,
    DataRecord,
    JobFolderError,
    KittiError,
    LossRecord,
    Overall,
    PoseErrors,
    Results,
    Scores,
    SequenceResult,
    Statistics,
)
from lossvo.report.against_baselines import BaselineRun, data_groups
from lossvo.report.cli import main
from lossvo.report.configurations import label_jobs, varying_keys
from lossvo.report.document import make_report
from lossvo.report.jobs import Job, ground_truth, parse_overrides, read_curves
from lossvo.report.tables import BASELINE, Column

LOSSES = STUDY_LOSSES
SEEDS = STUDY_SEEDS
SEQUENCES = STUDY_SEQUENCES
TRANSLATION = {"APE [m]": ("ape", "trans"), "RPE [m]": ("rpe", "trans")}
ROTATION = {"APE [rad]": ("ape", "rot_rad"), "RPE [rad]": ("rpe", "rot_rad")}


# --------------------------------------------------------------------------------------------------
# Fixtures: one real sweep and its report
# --------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sweep(study_sweep: Path) -> Path:
    """The session's shared sweep (read-only)."""
    return study_sweep


@pytest.fixture(scope="module")
def report(sweep: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The report folder of (a copy of) the sweep, with baselines."""
    copy = copy_sweep(sweep, tmp_path_factory.mktemp("report"))
    path = make_report(copy, n_jobs=1)
    assert path == copy / "report" / "report.md"
    return path.parent


def job_results(sweep: Path) -> dict[tuple[str, int], dict]:
    """{(loss, seed): results.json} read straight from the job folders' overrides and results."""
    out = {}
    for job in sweep.iterdir():
        overrides_file = job / ".hydra" / "overrides.yaml"
        if not overrides_file.is_file():
            continue
        overrides = dict(item.split("=", 1) for item in yaml.safe_load(overrides_file.read_text()))
        out[(overrides["loss"], int(overrides["seed"]))] = json.loads((job / "results.json").read_text())
    return out


def read_table(path: Path) -> dict[str, dict[str, str]]:
    """A report CSV as {sequence or "mean": {column header: cell}}."""
    with path.open() as f:
        return {row["sequence"]: row for row in csv.DictReader(f)}


def rmse(results: dict, sequence: str, metric: tuple[str, str]) -> float:
    return results["sequences"][sequence][metric[0]][metric[1]]["rmse"]


def copy_sweep(sweep: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(sweep, tmp_path / "sweep", ignore=shutil.ignore_patterns("report")))


# --------------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("table", "metrics_of"), [("translation", TRANSLATION), ("rotation", ROTATION)])
def test_cells_are_mean_and_sample_std_over_seeds_of_results_json(
    sweep: Path, report: Path, table: str, metrics_of: dict
) -> None:
    results = job_results(sweep)
    rows = read_table(report / "tables" / f"{table}.csv")
    assert set(rows) == {*SEQUENCES, "mean"}
    for loss in LOSSES:
        for header, metric in metrics_of.items():
            column = f"loss={loss} | {header}"
            per_seed = np.array([[rmse(results[(loss, s)], q, metric) for q in SEQUENCES] for s in SEEDS])
            for j, sequence in enumerate(SEQUENCES):
                assert float(rows[sequence][column]) == pytest.approx(per_seed[:, j].mean(), rel=1e-12)
                assert float(rows[sequence][f"{column} std"]) == pytest.approx(
                    per_seed[:, j].std(ddof=1), rel=1e-9
                )
                assert rows[sequence][f"{column} n"] == str(len(SEEDS))
            seed_means = per_seed.mean(axis=1)  # the mean row: each seed over the sequences, then over seeds
            assert float(rows["mean"][column]) == pytest.approx(seed_means.mean(), rel=1e-12)
            assert float(rows["mean"][f"{column} std"]) == pytest.approx(seed_means.std(ddof=1), rel=1e-9)


def markdown_rows(report_md: str, title: str) -> tuple[list[str], dict[str, list[str]]]:
    """Header and rows (by first cell) of the markdown table that follows ``## <title>``."""
    section = report_md.split(f"## {title}", 1)[1].splitlines()
    start = next(i for i, line in enumerate(section) if line.startswith("|"))
    table = []
    for line in section[start:]:
        if not line.startswith("|"):
            break
        table.append([cell.strip() for cell in line.strip("|").split("|")])
    header, body = table[0], table[2:]
    return header, {row[0].strip("*"): row for row in body}


def test_bold_marks_the_row_minimum_over_all_columns(report: Path) -> None:
    text = (report / "report.md").read_text()
    rows_csv = read_table(report / "tables" / "translation.csv")
    header, rows = markdown_rows(text, "Table I")
    latex = (report / "tables" / "translation.tex").read_text()
    bold_seen = 0
    for metric in TRANSLATION:
        columns = [h for h in header if h.endswith(f": {metric}")]
        assert len(columns) == len(LOSSES) + 5  # five baselines
        for sequence in (*SEQUENCES, "mean"):
            means = {c: float(rows_csv[sequence][c.replace(": ", " | ", 1)]) for c in columns}
            best = min(means, key=means.get)
            for c in columns:
                cell = rows[sequence][header.index(c)]
                assert cell.startswith("**") == (c == best), (sequence, c, cell, means)
            bold_seen += 1
    assert bold_seen == 2 * (len(SEQUENCES) + 1)
    assert latex.count(r"\textbf{") == bold_seen
    assert all(rule in latex for rule in (r"\toprule", r"\midrule", r"\bottomrule"))


def test_pairwise_comparison_pairs_seed_means_and_says_when_the_seeds_cannot_decide(
    sweep: Path, report: Path
) -> None:
    results = job_results(sweep)
    with (report / "tables" / "pairwise.csv").open() as f:
        rows = {row["metric"]: row for row in csv.DictReader(f)}
    a, b = (f"loss={loss}" for loss in LOSSES)
    row = rows["APE trans RMSE [m]"]
    assert (row["a"], row["b"]) == (a, b)
    # each seed's mean over the evaluated sequences, A - B, paired by seed
    ape = ("ape", "trans")
    diff = np.array([np.mean([rmse(results[(LOSSES[0], s)], q, ape) - rmse(results[(LOSSES[1], s)], q, ape)
                              for q in SEQUENCES]) for s in SEEDS])  # fmt: skip
    assert int(row["seeds"]) == len(SEEDS) and row["sequences"] == ";".join(sorted(SEQUENCES))
    assert float(row["mean_diff"]) == pytest.approx(diff.mean(), rel=1e-9)
    assert float(row["p_value"]) == pytest.approx(wilcoxon(diff, method="exact").pvalue, rel=1e-12)
    assert float(row["holm_p"]) == float(row["p_value"])  # one pair: a family of one
    assert row["verdict"] == f"cannot decide with {len(SEEDS)} seeds"  # 2 seeds: p >= 0.5


# --------------------------------------------------------------------------------------------------
# Baselines, checked against independent computations
# --------------------------------------------------------------------------------------------------


def read_pose_file(path: Path) -> np.ndarray:
    """KITTI poses (N, 4, 4) with plain numpy, independent of lossvo's reader."""
    values = np.loadtxt(path).reshape(-1, 3, 4)
    poses = np.tile(np.eye(4), (len(values), 1, 1))
    poses[:, :3, :] = values
    return poses


def scores(gt: np.ndarray, est: np.ndarray) -> dict:
    """evo's APE and RPE (delta 1 frame, no alignment) RMSEs: ``{kind: {"trans" | "rot_rad": {"rmse"}}}``."""
    relations = {"trans": evo_metrics.PoseRelation.translation_part,
                 "rot_rad": evo_metrics.PoseRelation.rotation_angle_rad}  # fmt: skip
    out: dict = {}
    for kind in ("ape", "rpe"):
        for name, relation in relations.items():
            metric = evo_metrics.APE(relation) if kind == "ape" else evo_metrics.RPE(relation, delta=1)
            metric.process_data((PosePath3D(poses_se3=list(gt)), PosePath3D(poses_se3=list(est))))
            out.setdefault(kind, {})[name] = {"rmse": metric.get_statistic(evo_metrics.StatisticsType.rmse)}
    return out


def check_zero_and_mean_motion(
    report: Path, root: Path, train: tuple[str, ...], sequences: tuple[str, ...]
) -> None:
    """The report's zero-motion and training-mean-motion cells equal scores computed here, with plain
    numpy from the pose files under ``root``."""
    rows = read_table(report / "tables" / "translation.csv")
    rot_rows = read_table(report / "tables" / "rotation.csv")
    poses = [read_pose_file(root / "poses" / f"{n}.txt") for n in train]
    steps = np.concatenate([np.linalg.inv(p[:-1]) @ p[1:] for p in poses])
    u, _, vt = np.linalg.svd(steps[:, :3, :3].mean(axis=0))
    mean_step = np.eye(4)
    mean_step[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    mean_step[:3, 3] = steps[:, :3, 3].mean(axis=0)
    for sequence in sequences:
        gt = read_pose_file(root / "poses" / f"{sequence}.txt")
        standing = np.repeat(gt[:1], len(gt), axis=0)  # zero motion: the first pose forever
        chained = [gt[0]]
        for _ in range(len(gt) - 1):
            chained.append(chained[-1] @ mean_step)
        for name, est in (("zero motion", standing), ("mean motion (train)", np.stack(chained))):
            expected = scores(gt, est)
            for header, metric in TRANSLATION.items():
                got = float(rows[sequence][f"{name} | {header}"])
                assert got == pytest.approx(expected[metric[0]][metric[1]]["rmse"], rel=1e-6), (name, header)
            for header, metric in ROTATION.items():
                got = float(rot_rows[sequence][f"{name} | {header}"])
                assert got == pytest.approx(expected[metric[0]][metric[1]]["rmse"], rel=1e-6, abs=1e-9)


def test_zero_and_mean_motion_baselines_equal_an_independent_computation(
    tiny_kitti: Path, report: Path
) -> None:
    check_zero_and_mean_motion(report, tiny_kitti, ("00", "01"), SEQUENCES)


def test_orb_baseline_uses_gt_scale_and_beats_standing_still(report: Path) -> None:
    rows = read_table(report / "tables" / "translation.csv")
    rot = read_table(report / "tables" / "rotation.csv")
    text = (report / "report.md").read_text()
    failures = re.search(r"ORB\+E failed \(fell back\) on (\d+) of (\d+) frame pairs", text)
    assert failures is not None and int(failures[2]) == 9 * len(SEQUENCES)
    for sequence in SEQUENCES:
        orb = float(rows[sequence]["ORB+E (GT scale) | RPE [m]"])
        zero = float(rows[sequence]["zero motion | RPE [m]"])  # = the ground-truth step length
        assert 0 < orb < 0.6 * zero, (sequence, orb, zero)  # right step lengths, roughly right directions
        assert 0 < float(rot[sequence]["ORB+E (GT scale) | RPE [rad]"]) < 0.2


def test_baselines_are_cached_per_sequence(sweep: Path, report: Path, tmp_path: Path) -> None:
    out = tmp_path / "again"
    shutil.copytree(report / "cache", out / "cache")
    make_report(sweep, out, n_jobs=1, with_figures=False)
    text = (out / "report.md").read_text()
    assert f"{len(SEQUENCES)} of {len(SEQUENCES)} sequences from the report's `cache/`" in text
    assert (out / "tables" / "translation.csv").read_text() == (
        report / "tables" / "translation.csv"
    ).read_text()


# --------------------------------------------------------------------------------------------------
# Partial and damaged sweeps, other sweep axes, single seed
# --------------------------------------------------------------------------------------------------


def test_failed_running_and_corrupt_jobs_are_listed_and_skipped(sweep: Path, tmp_path: Path) -> None:
    copy = copy_sweep(sweep, tmp_path)
    jobs = {job.name.split("_", 1)[0]: job for job in copy.iterdir() if job.is_dir()}
    (jobs["1"] / "results.json").write_text('{"sequences": {"00": ')  # euler, seed 1: cut mid-write
    status = {"status": "failed", "error": "RuntimeError: boom"}
    (jobs["2"] / "status.json").write_text(json.dumps(status))  # quat, seed 0
    metrics_csv = jobs["3"] / "metrics.csv"  # quat, seed 1: metrics.csv cut mid-line, results intact
    metrics_csv.write_text(metrics_csv.read_text()[:-25])
    running = copy / "4_experiment-tiny+loss-chordal+seed-0"
    shutil.copytree(jobs["0"] / ".hydra", running / ".hydra")
    (running / ".hydra" / "overrides.yaml").write_text("- experiment=tiny\n- loss=chordal\n- seed=0\n")
    (running / "status.json").write_text('{"status": "running"}')

    path = make_report(copy, with_baselines=False, with_figures=False)
    text = path.read_text()
    _, listed = markdown_rows(text, "Jobs")
    assert "results.json: invalid JSON" in listed[f"`{jobs['1'].name}`"][4]
    assert "failed: RuntimeError: boom" in listed[f"`{jobs['2'].name}`"][4]
    assert (
        listed[f"`{jobs['3'].name}`"][4] == "yes" and "metrics.csv line" in listed[f"`{jobs['3'].name}`"][5]
    )
    assert "still running" in listed[f"`{running.name}`"][4]
    assert "5 job(s): 2 included, 3 skipped" in text

    results = job_results(sweep)
    rows = read_table(path.parent / "tables" / "translation.csv")
    assert not any(h.startswith("loss=chordal") for h in rows["00"])  # a running job has no column
    for loss, seed in (("euler", 0), ("quat", 1)):  # the one usable seed of each loss
        for sequence in SEQUENCES:
            assert float(rows[sequence][f"loss={loss} | APE [m]"]) == rmse(results[(loss, seed)], sequence,
                                                                           ("ape", "trans"))  # fmt: skip
            assert rows[sequence][f"loss={loss} | APE [m] n"] == "1"
    assert "no seed-noise estimate" in text


def test_single_seed_says_no_seed_noise_estimate(sweep: Path, tmp_path: Path) -> None:
    copy = copy_sweep(sweep, tmp_path)
    for job in copy.iterdir():
        if job.is_dir() and "seed-1" in job.name:
            shutil.rmtree(job)
    text = make_report(copy, with_baselines=False, with_figures=False).read_text()
    assert "One seed per configuration" in text and "no seed-noise estimate is available" in text
    assert "n/a (one seed: no seed-noise estimate)" in text
    assert " ± " not in markdown_rows(text, "Table I")[1]["00"][1]


def test_columns_are_named_by_the_overrides_that_differ() -> None:
    def job(*overrides: str) -> Job:
        return Job(Path("job"), overrides=parse_overrides(overrides))

    jobs = [job("loss=chordal", "loss.k=50", "seed=0", "trainer.max_epochs=3"),
            job("loss=chordal", "loss.k=100", "seed=0", "trainer.max_epochs=3"),
            job("loss=chordal", "loss.k=50", "seed=1", "trainer.max_epochs=3")]  # fmt: skip
    assert varying_keys(jobs) == ["loss.k"]
    label_jobs(jobs)
    assert [j.label for j in jobs] == ["loss.k=50", "loss.k=100", "loss.k=50"]
    jobs = [job("+evaluate=false", "loss=euler", "seed=0"), job("+evaluate=false", "loss=euler", "seed=1")]
    label_jobs(jobs)  # only seeds differ: one configuration, named by its overrides
    assert {j.label for j in jobs} == {"evaluate=false,loss=euler"}


def test_a_label_names_its_configuration_first_whatever_order_the_jobs_are_read_in() -> None:
    def job(*overrides: str) -> Job:
        parsed = parse_overrides(overrides)
        return Job(Path("job"), overrides=parsed, architecture=parsed.get("model"))

    jobs = [job("loss=euler", "experiment=mix", "seed=0"), job("model=flowvo", "loss=quat", "seed=0")]
    for ordered in (jobs, jobs[::-1]):
        assert varying_keys(ordered) == ["experiment", "model", "loss"]
        label_jobs(ordered)
        assert [j.label for j in jobs] == ["experiment=mix,loss=euler", "model=flowvo,loss=quat"]


def test_settings_of_each_training_data_do_not_name_configurations() -> None:
    def job(*overrides: str) -> Job:
        parsed = parse_overrides(overrides)
        return Job(Path("job"), overrides=parsed, data=parsed.get("data"))

    mix, car = ("data=mix", "data.sources.drone.root=/d"), ("data=synthetic",)
    jobs = [job(*data, f"loss={loss}", "seed=0") for data in (mix, car) for loss in ("euler", "quat")]
    assert varying_keys(jobs) == ["data", "loss"]  # the drone's folder comes with data=mix
    label_jobs(jobs)
    expected = [f"data={d},loss={loss}" for d in ("mix", "synthetic") for loss in ("euler", "quat")]
    assert [j.label for j in jobs] == expected
    jobs.append(job("data=mix", "data.sources.drone.root=/e", "loss=euler", "seed=0"))  # a second folder
    assert varying_keys(jobs) == ["data", "data.sources.drone.root", "loss"]


def test_truncated_metrics_csv_keeps_the_complete_rows(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    path.write_text(
        "epoch,step,train/loss,val/loss\n,0,,\n0,5,,2.0\n0,5,3.0,\n1,11,,1.5\n1,11,2.5,\n2,17,,1.2"
        "\n2,17,2.2\n"  # the last row lost its last field
    )
    curves, notes = read_curves(tmp_path)
    epochs, values = curves.series["val/loss"]
    assert epochs.tolist() == [0, 1, 2] and values.tolist() == [2.0, 1.5, 1.2]
    assert curves.series["train/loss"][1].tolist() == [3.0, 2.5]
    assert len(notes) == 1 and "line 8" in notes[0]


# --------------------------------------------------------------------------------------------------
# Figures and the command line
# --------------------------------------------------------------------------------------------------


def png_size(path: Path) -> tuple[int, int]:
    header = path.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", header[16:24])


def test_figures_are_pngs_of_every_sequence(report: Path) -> None:
    figures = report / "figures"
    names = sorted(p.name for p in figures.glob("*.png"))
    assert names == sorted(["curves.png", "ape_trans_rmse.png", *(f"trajectory_{s}.png" for s in SEQUENCES)])
    for name in names:
        width, height = png_size(figures / name)
        assert width > 300 and height > 200, (name, width, height)
    text = (report / "report.md").read_text()
    assert all(f"(figures/{name})" in text for name in names)


def test_a_single_architecture_sweep_has_no_architecture_column_section_or_file(report: Path) -> None:
    assert "architecture" not in (report / "report.md").read_text().lower()
    tables = {p.name for p in (report / "tables").iterdir()}
    per_sequence = {f"{t}.{ext}" for t in ("translation", "rotation", "kitti") for ext in ("csv", "tex")}
    assert tables == per_sequence | {
        "pairwise.csv",
        "configurations.csv",
        "convergence.csv",
        "claims.csv",
        "speed.csv",
    }
    assert not any("architecture" in (report / "tables" / name).read_text() for name in tables)


def test_latest_reports_the_newest_sweep_and_prints_the_path(
    sweep: Path, report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main(["--latest", str(sweep.parent), "--out", str(out), "--no-baselines"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == str(out / "report.md")
    rows = read_table(out / "tables" / "translation.csv")
    assert not any(h.startswith("zero motion") for h in rows["00"])  # --no-baselines
    assert "(`--no-baselines`)" in (out / "report.md").read_text()


# --------------------------------------------------------------------------------------------------
# Configurations, convergence and the study's claims
# --------------------------------------------------------------------------------------------------

GAINS = {"EulerLoss": 1.0, "QuaternionLoss": 0.25, "ChordalLoss": 2.0}  # rotation term ~ gain * theta^2


def job_configs(sweep: Path) -> dict[str, tuple[Path, dict]]:
    """{job folder name: (folder, .hydra/config.yaml as plain YAML, interpolations unresolved)}."""
    return {
        job.name: (job, yaml.safe_load((job / ".hydra" / "config.yaml").read_text()))
        for job in sweep.iterdir()
        if (job / ".hydra" / "config.yaml").is_file()
    }


def section(text: str, title: str) -> str:
    """The text of ``## <title>`` up to the next ``## `` heading."""
    return text.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_configurations_list_k_times_gain_and_the_selection_metric(sweep: Path, report: Path) -> None:
    text = (report / "report.md").read_text()
    header, rows = markdown_rows(text, "Configurations")
    configs = {name: cfg for name, (_, cfg) in job_configs(sweep).items()}
    for loss in LOSSES:
        cfg = next(c for name, c in configs.items() if f"loss-{loss}+" in name)
        row = dict(zip(header, rows[f"loss={loss}"], strict=True))
        gain = GAINS[cfg["loss"]["_target_"].rsplit(".", 1)[-1]]
        k = cfg["loss"]["k"]
        if not isinstance(k, (int, float)):  # the matched preset's k = c / gain, interpolated
            assert cfg["weighting"]["preset"] == "matched"
            k = cfg["weighting"]["c"] / gain
        assert float(row["rotation weight k·gain"]) == pytest.approx(k * gain, rel=1e-3)
        assert row["selected by"] == f"`{cfg['selection']['monitor']}` ({cfg['selection']['mode']})"
    assert "**Warning" not in text  # every job of the default study is selected by val/score


def test_different_selection_metrics_give_a_bold_warning_at_the_top(sweep: Path, tmp_path: Path) -> None:
    copy = copy_sweep(sweep, tmp_path)
    for name, (job, cfg) in job_configs(copy).items():
        if "loss-quat" in name:
            cfg["selection"] = {"monitor": "val/loss", "mode": "min"}
            (job / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    text = make_report(copy, with_baselines=False, with_figures=False).read_text()
    top = text.split("\n## ", 1)[0]
    warning = next(line for line in top.splitlines() if line.startswith("**Warning"))
    assert warning.endswith("**") and "selected by different metrics" in warning
    assert "loss=quat: `val/loss` (min)" in warning and "loss=euler: `val/score` (min)" in warning


def test_jobs_of_different_code_versions_and_machines_are_named_and_pooled(
    sweep: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    copy = copy_sweep(sweep, tmp_path)
    names = sorted(p.name for p in copy.iterdir() if (p / "status.json").is_file())
    versions = {
        name: json.loads((copy / name / "status.json").read_text())["history"][0]["code"] for name in names
    }
    assert len(set(versions.values())) == 1  # one sweep: one version, recorded when each job started
    text = make_report(copy, with_baselines=False, with_figures=False).read_text()
    assert "code versions" not in text
    status = json.loads((copy / names[0] / "status.json").read_text())
    status["history"][0]["code"] = "0.0.9+000000000000"
    (copy / names[0] / "status.json").write_text(json.dumps(status))
    with caplog.at_level("WARNING", logger="lossvo"):
        text = make_report(copy, with_baselines=False, with_figures=False).read_text()
    top = text.split("\n## ", 1)[0]
    note = next(line for line in top.splitlines() if "code versions" in line)
    assert note.startswith("**The included jobs ran 2 code versions**, pooled in every table and test")
    assert f"`0.0.9+000000000000`: {names[0]}" in note and f"`{versions[names[1]]}`: {names[1]}" in note
    assert any("ran 2 code versions" in r.message for r in caplog.records)
    assert "machines" not in top  # one machine trained them all
    status["history"][0]["machine"] = "Other CPU, AVX2, flags 00000000"
    (copy / names[0] / "status.json").write_text(json.dumps(status))
    top = make_report(copy, with_baselines=False, with_figures=False).read_text().split("\n## ", 1)[0]
    note = next(line for line in top.splitlines() if "machines" in line)
    assert note.startswith("**The included jobs ran on 2 machines**, pooled in every table and test")
    assert f"`Other CPU, AVX2, flags 00000000`: {names[0]}" in note and names[1] in note


def first_within_ten_percent(path: Path, column: str = "val/score") -> int:
    """The 1-based epoch at which ``column`` first comes within 10 % of its minimum, from metrics.csv read
    with the csv module (the last value logged in an epoch counts)."""
    per_epoch: dict[int, float] = {}
    with path.open() as f:
        for row in csv.DictReader(f):
            if row["epoch"] and row.get(column):
                per_epoch[int(row["epoch"])] = float(row[column])
    best = min(per_epoch.values())
    return min(e for e, v in per_epoch.items() if v <= best * 1.1) + 1


def test_convergence_epochs_match_the_jobs_metrics_csv(sweep: Path, report: Path) -> None:
    with (report / "tables" / "convergence.csv").open() as f:
        rows = {(r["configuration"], r["seed"]): r for r in csv.DictReader(f)}
    for name, (job, _) in job_configs(sweep).items():
        loss, seed = re.search(r"loss-(\w+)\+seed-(\d+)", name).groups()
        row = rows[(f"loss={loss}", f"seed={seed}")]
        assert row["metric"] == "val/score"
        assert int(row["epoch"]) == first_within_ten_percent(job / "metrics.csv")
    for loss in LOSSES:
        epochs = [int(rows[(f"loss={loss}", f"seed={s}")]["epoch"]) for s in SEEDS]
        assert float(rows[(f"loss={loss}", "mean")]["epoch"]) == pytest.approx(np.mean(epochs))
    assert "| loss=euler | val/score | 2 |" in section((report / "report.md").read_text(), "Convergence")


def test_claims_section_is_last_and_cannot_be_tested_without_chordal(report: Path) -> None:
    text = (report / "report.md").read_text()
    titles = re.findall(r"^## (.+)$", text, flags=re.MULTILINE)
    assert titles[-1] == "The study's claims"
    assert (
        section(text + "\n## end", "The study's claims").count("Cannot be tested: the sweep has no chordal")
        == 2
    )
    with (report / "tables" / "claims.csv").open() as f:
        assert [r["verdict"] for r in csv.DictReader(f)] == ["cannot be tested"] * 2


def test_claims_test_the_chordal_loss_class_on_held_out_sequences(sweep: Path, tmp_path: Path) -> None:
    copy = copy_sweep(sweep, tmp_path)
    for name, (job, cfg) in job_configs(copy).items():
        if "loss-quat" in name:  # the report must find the chordal configuration by its loss class
            cfg["loss"]["_target_"] = "lossvo.losses.ChordalLoss"
            (job / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    path = make_report(copy, with_baselines=False, with_figures=False)
    results = job_results(sweep)
    held_out = [s for s in SEQUENCES if s not in ("00", "01")]  # data.splits.train of the tiny experiment
    with (path.parent / "tables" / "claims.csv").open() as f:
        rows = {(r["claim"], r["quantity"]): r for r in csv.DictReader(f)}
    row = rows[("the chordal loss gives the lowest errors", "RPE trans RMSE [m]")]
    assert (row["configuration"], row["versus"]) == ("loss=quat", "loss=euler")
    # each seed's mean over the held-out sequences, paired by seed
    rpe = ("rpe", "trans")
    x, y = (np.array([np.mean([rmse(results[(loss, s)], q, rpe) for q in held_out]) for s in SEEDS])
            for loss in ("quat", "euler"))  # fmt: skip
    assert int(row["n_seeds"]) == x.size == len(SEEDS)
    assert float(row["mean"]) == pytest.approx(x.mean()) and float(row["versus_mean"]) == pytest.approx(
        y.mean()
    )
    assert float(row["p_value"]) == pytest.approx(wilcoxon(x - y, method="exact").pvalue, rel=1e-12)
    cells = [np.array([rmse(results[(loss, s)], q, rpe) for s in SEEDS for q in held_out])
             for loss in ("quat", "euler")]  # fmt: skip
    assert int(row["secondary_cells"]) == len(SEEDS) * len(held_out)
    assert float(row["secondary_p"]) == pytest.approx(wilcoxon(cells[0] - cells[1]).pvalue)
    r = (x - y) / y  # 2 seeds: p >= 0.5 whatever the numbers, so only equivalence can decide
    ci = ttest_1samp(r, 0.0).confidence_interval(0.90)
    inside = ci.low > -0.05 and ci.high < 0.05
    assert (float(row["relative_low_90"]), float(row["relative_high_90"])) == (
        pytest.approx(ci.low, abs=1e-12),
        pytest.approx(ci.high, abs=1e-12),
    )
    assert row["verdict"] == ("equivalent" if inside else "cannot decide at this n")
    text = path.read_text()
    assert "**Verdict: cannot decide at this n.** 2 seeds cannot decide: the smallest p" in text  # claim (b)


def test_each_job_is_compared_with_the_mean_motion_on_the_validation_sequences(
    sweep: Path, report: Path
) -> None:
    text = (report / "report.md").read_text()
    section = text.split("## Against the mean motion, per job", 1)[1].split("\n## ", 1)[0]
    rows = [line.strip("|").split("|") for line in section.splitlines() if line.startswith("| ")]
    header, body = [c.strip() for c in rows[0]], [[c.strip() for c in r] for r in rows[1:]]
    assert header == [
        "configuration",
        "seed",
        "02 RPE trans",
        "02 RPE rot",
    ]  # the tiny sweep's data.splits.val
    assert len(body) == len(LOSSES) * len(SEEDS)
    translation = read_table(report / "tables" / "translation.csv")
    rotation = read_table(report / "tables" / "rotation.csv")
    baseline = {"trans": float(translation["02"]["mean motion (train) | RPE [m]"]),
                "rot_rad": float(rotation["02"]["mean motion (train) | RPE [rad]"])}  # fmt: skip
    results = job_results(sweep)
    for label, seed, trans, rot in body:
        job = results[(label.removeprefix("loss="), int(seed))]
        for cell, kind in ((trans, "trans"), (rot, "rot_rad")):
            expected = 100 * (1 - rmse(job, "02", ("rpe", kind)) / baseline[kind])
            assert float(cell.removesuffix(" %")) == pytest.approx(expected, abs=0.5 + 1e-9)


# --------------------------------------------------------------------------------------------------
# Unseen motion: hand-written job folders and baselines, no training
# --------------------------------------------------------------------------------------------------

UNSEEN = ("11", "12")


def statistics(rmse: float) -> Statistics:
    """Error statistics with the given RMSE (m or rad)."""
    return Statistics(rmse=rmse, mean=rmse, median=rmse, std=0.0, min=rmse, max=rmse)


def entry(rpe_trans: float, rpe_rot: float) -> Scores:
    """A sequence's scores with the given RPE RMSEs (m, rad); APE and KITTI errors fixed."""
    return Scores(
        PoseErrors(statistics(5.0), statistics(0.1)),
        PoseErrors(statistics(rpe_trans), statistics(rpe_rot)),
        KittiError(10.0, 5.0),
    )


def data_record(root: Path, test: list[str], unseen: list[str], train: list[str] | None = None) -> DataRecord:
    """results.json's ``data``: a job evaluated on the KITTI-layout dataset at ``root`` that it was
    trained on (split ``train``, default 00)."""
    return DataRecord("lossvo.data.datamodules.KittiDataModule", str(root), test, unseen, str(root),
                      train or ["00"], 64, 208, 3, "dataset", [0.4] * 3, [0.2] * 3)  # fmt: skip


def results_json(record: DataRecord, sequences: dict[str, Scores]) -> Results:
    """A results.json of a job evaluated on ``record``'s data: per sequence its scores, trajectory file and
    ground truth ``<root>/poses/NN.txt``, unseen if ``record`` lists it."""
    poses = Path(record.root) / "poses"
    entries = {
        s: SequenceResult(10, f"trajectories/{s}.txt", f"plots/{s}.png", str(poses / f"{s}.txt"),
                          s in record.unseen, scores)
        for s, scores in sequences.items()
    }  # fmt: skip
    overall = Overall([], note="pooled scores not computed by this test")
    return Results(None, LossRecord("EulerLoss", 100.0), "none", 1, 3, False, record, entries, overall)


def write_job(sweep: Path, number: int, loss: str, data: dict, sequences: dict, record: DataRecord) -> Path:
    """A completed job folder: .hydra/{config,overrides}.yaml (config ``data`` and the selection metric),
    status.json and results.json (:func:`results_json`)."""
    job = sweep / f"{number}_loss-{loss}+seed-0"
    (job / ".hydra").mkdir(parents=True)
    config = {"seed": 0, "data": data, "selection": {"monitor": "val/score", "mode": "min"}}
    (job / ".hydra" / "config.yaml").write_text(yaml.safe_dump(config))
    (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump([f"loss={loss}", "seed=0"]))
    (job / "status.json").write_text('{"status": "completed"}')
    results_json(record, sequences).write(job / "results.json")
    return job


def hand_sweep(tmp_path: Path, unseen: list[str] | None) -> Path:
    """Two jobs on 07 and the unseen sequences against zero motion (RPE rot 0.05 rad) and the own mean
    motion (RPE trans 0.2 m): euler is 60 % below zero motion in rotation and 25 % below the oracle in
    translation on both; quat is only 20 % below zero motion in rotation on 12. The unseen sequences are
    in results.json (and not in the config)."""
    sweep = tmp_path / "sweep"
    data = {"train": ["00"], "val": ["07"]}
    record = data_record(tmp_path / "data", ["07", *UNSEEN], unseen or [])
    good = {"07": entry(0.1, 0.01), "11": entry(0.15, 0.02), "12": entry(0.15, 0.02)}
    write_job(sweep, 0, "euler", data, good, record)
    write_job(sweep, 1, "quat", data, {**good, "12": entry(0.1, 0.04)}, record)
    return sweep


def hand_baselines(*_: object) -> BaselineRun:
    """What :func:`lossvo.report.against_baselines.run_baselines` returns, with fixed numbers on 07, 11
    and 12."""
    values = {"zero motion": (1.0, 0.05), "mean motion (train)": (0.3, 0.05),
              "ORB+E (GT scale)": (0.5, 0.03), "own mean motion (oracle)": (0.2, 0.04)}  # fmt: skip
    columns = [
        Column(name, BASELINE, ["deterministic"], [{s: entry(*v) for s in ("07", *UNSEEN)}])
        for name, v in values.items()
    ]
    return BaselineRun(columns=columns)


def unseen_rows(text: str) -> dict[tuple[str, str], dict[str, str]]:
    """The rows of the *Unseen motion* table by (configuration, sequence)."""
    header, _ = markdown_rows(text, "Unseen motion")
    body = section(text, "Unseen motion").splitlines()
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in body if line.startswith("| ")][1:]
    return {(r[0], r[2]): dict(zip(header, r, strict=True)) for r in rows}


def test_unseen_motion_section_marks_which_jobs_meet_both_criteria(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("lossvo.report.document.run_baselines", hand_baselines)
    path = make_report(hand_sweep(tmp_path, list(UNSEEN)), with_figures=False)
    text = path.read_text()
    rows = unseen_rows(text)
    assert set(rows) == {(f"loss={loss}", s) for loss in ("euler", "quat") for s in UNSEEN}
    assert rows[("loss=euler", "12")]["vs zero motion"] == "60.0 %"
    assert rows[("loss=euler", "12")]["vs own mean motion"] == "25.0 %"
    assert rows[("loss=quat", "12")]["vs zero motion"] == "20.0 %"
    assert rows[("loss=quat", "12")]["vs own mean motion"] == "50.0 %"
    met = {key: row["both met"] for key, row in rows.items()}
    assert met == {("loss=euler", "11"): "yes", ("loss=euler", "12"): "yes",
                   ("loss=quat", "11"): "yes", ("loss=quat", "12"): "no"}  # fmt: skip
    assert "1 of 2 jobs meet both on every unseen sequence." in section(text, "Unseen motion")
    _, table = markdown_rows(text, "Table I")
    assert {"07", "11 (unseen motion)", "12 (unseen motion)", "mean"} == set(table)
    csv_rows = read_table(path.parent / "tables" / "translation.csv")
    assert {s: r["note"] for s, r in csv_rows.items()} == {"07": "", "11": "unseen motion",
                                                           "12": "unseen motion", "mean": ""}  # fmt: skip
    assert float(csv_rows["11"]["own mean motion (oracle) | RPE [m]"]) == 0.2
    latex = (path.parent / "tables" / "translation.tex").read_text()
    assert "\n11 (unseen motion) & " in latex and "\n07 & " in latex
    assert "**own mean motion (oracle)**" in section(text, "Baselines")


@pytest.mark.parametrize(("unseen", "with_baselines"), [(None, True), ([], True), (list(UNSEEN), False)])
def test_no_unseen_motion_section_without_unseen_sequences_or_baselines(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, unseen: list[str] | None, with_baselines: bool
) -> None:
    monkeypatch.setattr("lossvo.report.document.run_baselines", hand_baselines)
    path = make_report(hand_sweep(tmp_path, unseen), with_baselines=with_baselines, with_figures=False)
    text = path.read_text()
    assert "## Unseen motion" not in text
    assert "## Against the mean motion, per job" in text or not with_baselines
    assert ("(unseen motion)" in text) == bool(unseen)  # the table marks need no baselines


def test_unseen_marks_come_from_results_json_before_the_config(tmp_path: Path) -> None:
    sweep = hand_sweep(tmp_path, [])  # results.json: no unseen-motion sequence
    for config in sweep.glob("*/.hydra/config.yaml"):
        content = yaml.safe_load(config.read_text())
        content["data"]["unseen"] = list(UNSEEN)
        config.write_text(yaml.safe_dump(content))
    text = make_report(sweep, with_baselines=False, with_figures=False).read_text()
    assert "(unseen motion)" not in text
    for results in sweep.glob("*/results.json"):  # one sequence flagged, none listed
        content = json.loads(results.read_text())
        content["sequences"]["12"]["unseen"] = True
        results.write_text(json.dumps(content))
    _, table = markdown_rows(
        make_report(sweep, with_baselines=False, with_figures=False).read_text(), "Table I"
    )
    assert set(table) == {"07", "11", "12 (unseen motion)", "mean"}


# --------------------------------------------------------------------------------------------------
# What the report reads: hand-written job folders, the data they record on the tiny dataset, no training
# --------------------------------------------------------------------------------------------------

EVALUATED = ("01", "02")


def forbid_datamodules(monkeypatch: pytest.MonkeyPatch) -> None:
    """Building a config's object (a datamodule) fails the test."""

    def forbidden(*_: object, **__: object) -> None:
        raise AssertionError("the report must build no datamodule")

    monkeypatch.setattr("hydra.utils.instantiate", forbidden)


def output_sweep(tmp_path: Path, root: Path, kind: str | None = None) -> Path:
    """Two jobs evaluated on 01 and 02 of the dataset at ``root`` (trained on 00), their trajectories
    the ground truth shifted 0.5 m along x; results.json with its data record (of ``kind``)."""
    sweep = tmp_path / "sweep"
    data = data_record(root, list(EVALUATED), [])
    data = replace(data, kind=kind) if kind else data
    for number, loss in enumerate(("euler", "quat")):
        sequences = {s: entry(0.1 + 0.01 * number, 0.01) for s in EVALUATED}
        job = write_job(sweep, number, loss, {"train": ["00"], "val": ["02"]}, sequences, data)
        for s in EVALUATED:
            if (root / "poses" / f"{s}.txt").is_file():
                shifted = read_pose_file(root / "poses" / f"{s}.txt")
                shifted[:, 0, 3] += 0.5
                (job / "trajectories").mkdir(exist_ok=True)
                np.savetxt(job / "trajectories" / f"{s}.txt", shifted[:, :3, :].reshape(-1, 12))
    return sweep


@pytest.mark.slow
def test_baselines_and_ground_truth_come_from_the_data_results_json_records(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    forbid_datamodules(monkeypatch)
    path = make_report(output_sweep(tmp_path, tiny_kitti), n_jobs=1)
    text = path.read_text()
    check_zero_and_mean_motion(path.parent, tiny_kitti, ("00",), EVALUATED)
    rows = read_table(path.parent / "tables" / "translation.csv")
    assert all(float(rows[s]["ORB+E (GT scale) | RPE [m]"]) > 0 for s in EVALUATED)
    assert "baselines skipped" not in text and "without ground truth" not in text
    for s in EVALUATED:
        assert f"(figures/trajectory_{s}.png)" in text
        assert png_size(path.parent / "figures" / f"trajectory_{s}.png")[0] > 300


@pytest.mark.slow
def test_each_sequence_gets_the_baselines_and_ground_truth_of_the_data_that_evaluated_it(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two jobs trained on different data (00; 01), each evaluated on its own sequence (01; 02): each
    sequence's mean motion is its own job's training split's, and both have ground truth."""
    forbid_datamodules(monkeypatch)
    sweep = tmp_path / "sweep"
    for number, (loss, train, evaluated) in enumerate((("euler", "00", "01"), ("quat", "01", "02"))):
        record = data_record(tiny_kitti, [evaluated], [], train=[train])
        job = write_job(sweep, number, loss, {"train": [train]}, {evaluated: entry(0.1, 0.01)}, record)
        (job / "trajectories").mkdir()
        gt = read_pose_file(tiny_kitti / "poses" / f"{evaluated}.txt")
        np.savetxt(job / "trajectories" / f"{evaluated}.txt", gt[:, :3, :].reshape(-1, 12))
    path = make_report(sweep, n_jobs=1)
    check_zero_and_mean_motion(path.parent, tiny_kitti, ("00",), ("01",))
    check_zero_and_mean_motion(path.parent, tiny_kitti, ("01",), ("02",))
    text = path.read_text()
    assert "baselines skipped" not in text and "without ground truth" not in text


def test_jobs_are_grouped_by_their_data_for_the_baselines(tmp_path: Path) -> None:
    """Each data's first job takes the sequences its jobs evaluated that no earlier data did; a sequence
    evaluated on two data is named in a note."""
    x, y = (data_record(tmp_path, [], [], train=[t]) for t in ("00", "01"))
    jobs = [
        Job(tmp_path / name, results=results_json(record, {s: entry(0.1, 0.01) for s in evaluated}))
        for name, record, evaluated in (("a", x, ["01"]), ("b", y, ["02", "01"]), ("c", x, ["00"]))
    ]
    groups, notes = data_groups(jobs, ["00", "01", "02"])
    assert [(job.path.name, own) for job, own in groups] == [("a", ["00", "01"]), ("b", ["02"])]
    assert notes == ["jobs of different data evaluated 01: their baselines use the first one's"]
    groups, notes = data_groups(jobs[:1] + jobs[2:], ["00", "01", "02"])
    assert [(job.path.name, own) for job, own in groups] == [("a", ["00", "01"])] and notes == []


@pytest.mark.slow
def test_without_the_recorded_data_the_report_renders_and_says_why_once(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    forbid_datamodules(monkeypatch)
    gone = tmp_path / "synthetic"  # a synthetic dataset that was deleted: it must not be rendered again
    copy = Path(shutil.copytree(tiny_kitti, gone))
    sweep = output_sweep(tmp_path, copy, kind="lossvo.data.datamodules.SyntheticDataModule")
    shutil.rmtree(copy)
    path = make_report(sweep, n_jobs=1)
    text = path.read_text()
    reason = f"{gone}, no longer exists"
    assert text.count("*Note:* baselines skipped") == 1 and reason in section(text, "Baselines")
    assert section(text + "\n## end", "Figures").count("trajectory figures without ground truth") == 1
    assert not gone.exists()
    rows = read_table(path.parent / "tables" / "translation.csv")
    assert float(rows["01"]["loss=euler | RPE [m]"]) == 0.1 and not any(
        "zero motion" in h for h in rows["01"]
    )
    assert {p.name for p in (path.parent / "figures").glob("trajectory_*.png")} == {
        f"trajectory_{s}.png" for s in EVALUATED
    }


def test_ground_truth_is_read_from_the_pose_file_results_json_names(tiny_kitti: Path, tmp_path: Path) -> None:
    elsewhere = tmp_path / "elsewhere.txt"
    shutil.copyfile(tiny_kitti / "poses" / "02.txt", elsewhere)
    named = {"01": str(elsewhere), "02": None, "03": str(tmp_path / "missing.txt")}  # 04: not evaluated
    results = results_json(data_record(tiny_kitti, list(named), []), {s: entry(0.1, 0.01) for s in named})
    sequences = {s: replace(e, ground_truth=named[s]) for s, e in results.sequences.items()}
    job = Job(tmp_path / "0_job", results=replace(results, sequences=sequences))
    found, missing = ground_truth([job], ["01", "02", "03", "04"])
    assert set(found) == {"01"} and np.array_equal(found["01"], read_pose_file(elsewhere))
    assert set(missing) == {"02", "03", "04"}
    assert "names no ground-truth file" in missing["02"] and "missing.txt" in missing["03"]


# --------------------------------------------------------------------------------------------------
# The results.json contract
# --------------------------------------------------------------------------------------------------


def contract_example(root: Path) -> Results:
    """A results.json with every kind of entry: scores, a sequence without a KITTI segment, one without
    ground truth, pooled scores and a thread count."""
    record = data_record(root, ["01", "02", "11"], ["11"])
    results = results_json(record, {"01": entry(0.1, 0.01), "02": entry(0.2, 0.02)})
    short = replace(entry(0.3, 0.03), kitti=KittiError(None, None, "sequence too short"))
    blind = SequenceResult(5, "trajectories/11.txt", "plots/11.png", None, True, note="no ground truth")
    sequences = {**results.sequences, "02": replace(results.sequences["02"], scores=short), "11": blind}
    return replace(results, sequences=sequences, overall=Overall(["01", "02"], entry(0.15, 0.015)), threads=4)


def test_results_csv_is_the_same_scores_as_a_tidy_table(tmp_path: Path) -> None:
    """One row per scored sequence and overall × metric × part × statistic, each once, equal to
    results.json's; both written atomically (no temporary file left)."""
    results = contract_example(tmp_path)
    scaled = replace(entry(0.1, 0.01), rpe_scaled=entry(0.4, 0.04).rpe)
    results = replace(
        results, sequences={**results.sequences, "01": replace(results.sequences["01"], scores=scaled)}
    )
    results.write(tmp_path / "run" / "results.json")
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["results.csv", "results.json"]
    content = json.loads((tmp_path / "run" / "results.json").read_text())
    with (tmp_path / "run" / "results.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["sequence", "metric", "part", "statistic", "value"]
    keys = [(r["sequence"], r["metric"], r["part"], r["statistic"]) for r in rows]
    expected = []
    for name, where in [*content["sequences"].items(), ("overall", content["overall"])]:
        for metric in ("ape", "rpe", "rpe_scaled"):
            expected += [
                (name, metric, part, stat) for part, stats in where.get(metric, {}).items() for stat in stats
            ]
        if "kitti" in where:
            expected += [(name, "kitti", part, "mean") for part in ("t_err_pct", "r_err_deg_per_100m")]
    assert len(set(keys)) == len(keys) == 3 * 12 + 2 + 2 * (2 * 12 + 2) and sorted(keys) == sorted(expected)
    assert {key[0] for key in keys} == {"01", "02", "overall"}  # 11 has no ground truth
    for r in rows:
        where = content["overall"] if r["sequence"] == "overall" else content["sequences"][r["sequence"]]
        scores = where[r["metric"]]
        value = scores[r["part"]] if r["metric"] == "kitti" else scores[r["part"]][r["statistic"]]
        assert (None if r["value"] == "" else float(r["value"])) == value, r
    assert [r["value"] for r in rows if r["sequence"] == "02" and r["metric"] == "kitti"] == ["", ""]


def test_results_json_round_trip(tmp_path: Path) -> None:
    results = contract_example(tmp_path)
    results.write(tmp_path / "results.json")
    assert Results.read(tmp_path / "results.json") == results
    content = json.loads((tmp_path / "results.json").read_text())
    assert content["schema_version"] == SCHEMA_VERSION and content["threads"] == 4
    assert list(content) == [
        "schema_version",
        "checkpoint",
        "loss",
        "align",
        "delta",
        "seq_len",
        "carry_state",
        "mirror_average",
        "translation",
        "threads",
        "data",
        "sequences",
        "overall",
    ]
    assert content["loss"] == {"class": "EulerLoss", "k": 100.0}
    assert list(content["sequences"]["01"]) == [
        "frames",
        "trajectory",
        "plot",
        "ape",
        "rpe",
        "kitti",
        "ground_truth",
        "unseen",
    ]
    assert content["sequences"]["01"]["ape"]["trans"] == {
        "rmse": 5.0,
        "mean": 5.0,
        "median": 5.0,
        "std": 0.0,
        "min": 5.0,
        "max": 5.0,
    }
    assert content["sequences"]["02"]["kitti"] == {
        "t_err_pct": None,
        "r_err_deg_per_100m": None,
        "note": "sequence too short",
    }
    assert content["sequences"]["11"] == {
        "frames": 5,
        "trajectory": "trajectories/11.txt",
        "plot": "plots/11.png",
        "note": "no ground truth",
        "ground_truth": None,
        "unseen": True,
    }
    assert results.scored() == {"01": entry(0.1, 0.01), "02": results.sequences["02"].scores}
    assert results.unseen() == {"11"}


def damaged(content: dict, change: str) -> object:
    """``content`` (results.json as parsed) with one damage."""
    if change == "a list":
        return [content]
    if change == "no rmse":
        del content["sequences"]["01"]["ape"]["trans"]["rmse"]
    elif change == "rmse a string":
        content["sequences"]["01"]["rpe"]["rot_rad"]["rmse"] = "0.1"
    elif change == "sequences a list":
        content["sequences"] = list(content["sequences"])
    elif change == "no data":
        del content["data"]
    elif change == "train not names":
        content["data"]["train"] = "00"
    elif change == "neither scores nor note":
        del content["sequences"]["11"]["note"]
    elif change == "another schema":
        content["schema_version"] = SCHEMA_VERSION + 1
    elif change == "no schema":
        del content["schema_version"]
    return content


@pytest.mark.parametrize(
    ("damage", "reason"),
    [("missing", "no such file"), ("a folder", "unreadable"), ("binary", "unreadable"),
     ("cut", "invalid JSON"), ("a list", "expected an object"),
     ("no rmse", "sequences.01.ape.trans.rmse is missing"),
     ("rmse a string", "sequences.01.rpe.rot_rad.rmse: expected a number"),
     ("sequences a list", "sequences: expected an object"), ("no data", "data is missing"),
     ("train not names", "data.train: expected a list of sequence names"),
     ("neither scores nor note", "sequences.11: neither scores"),
     ("another schema", f"schema_version {SCHEMA_VERSION + 1} is not supported (supported: "
                        f"{SCHEMA_VERSION}); evaluate the checkpoint again (python -m lossvo.eval "
                        "ckpt_path=...)"),
     ("no schema", f"no schema_version (supported: {SCHEMA_VERSION}); evaluate the checkpoint again")],
)  # fmt: skip
def test_each_bad_results_json_is_one_line_naming_the_file_and_the_problem(
    tmp_path: Path, damage: str, reason: str
) -> None:
    path = tmp_path / "run" / "results.json"
    path.parent.mkdir()
    content = contract_example(tmp_path).to_json()
    if damage == "a folder":
        path.mkdir()
    elif damage == "binary":
        path.write_bytes(b"\xff\xfe\x00results")
    elif damage == "cut":
        path.write_text(json.dumps(content)[:-40])
    elif damage != "missing":
        path.write_text(json.dumps(damaged(content, damage)))
    with pytest.raises(JobFolderError) as caught:
        Results.read(path)
    message = str(caught.value)
    assert isinstance(caught.value, UserError) and len(message.splitlines()) == 1
    assert message.startswith(f"{path}: ") and reason in message, message
    assert caught.value.path == path and reason in caught.value.reason


def test_a_sweep_with_an_unreadable_results_json_lists_the_file_and_the_reason(tmp_path: Path) -> None:
    sweep = hand_sweep(tmp_path, [])
    quat = sweep / "1_loss-quat+seed-0" / "results.json"
    content = json.loads(quat.read_text())
    content["schema_version"] = SCHEMA_VERSION + 1
    quat.write_text(json.dumps(content))
    text = make_report(sweep, with_baselines=False, with_figures=False).read_text()
    assert "2 job(s): 1 included, 1 skipped" in text
    _, listed = markdown_rows(text, "Jobs")
    assert listed["`1_loss-quat+seed-0`"][4] == (
        f"no: results.json: schema_version {SCHEMA_VERSION + 1} is not supported (supported: "
        f"{SCHEMA_VERSION}); evaluate the checkpoint again (python -m lossvo.eval ckpt_path=...)"
    )
    assert listed["`0_loss-euler+seed-0`"][4] == "yes"
    _, table = markdown_rows(text, "Table I")
    assert not any("loss=quat" in h for h in markdown_rows(text, "Table I")[0]) and "07" in table


# --------------------------------------------------------------------------------------------------
# The package: no import cycles, no datamodule
# --------------------------------------------------------------------------------------------------

SRC = Path(__file__).resolve().parents[1] / "src"


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path, modules: set[str]) -> set[str]:
    """The lossvo modules a source file imports anywhere (inside functions and ``if TYPE_CHECKING:``
    too); ``from package import name`` counts as the submodule where ``name`` is one."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{alias.name}" for alias in node.names}
            out |= (subs & modules) or {node.module}
    return {name for name in out if name in modules}


def import_graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in (SRC / "lossvo").rglob("*.py")}
    return {name: imported(path, set(files)) - {name} for name, path in files.items()}


def reaches(graph: dict[str, set[str]], start: str, goal: str) -> bool:
    seen, todo = set(), list(graph[start])
    while todo:
        name = todo.pop()
        if name == goal:
            return True
        if name not in seen:
            seen.add(name)
            todo.extend(graph.get(name, ()))
    return False


def test_the_report_package_has_no_import_cycle_and_the_plot_no_report_import() -> None:
    graph = import_graph()
    ours = [m for m in graph if m.startswith(("lossvo.report", "lossvo.evaluation"))]
    assert "lossvo.report.jobs" in ours and "lossvo.evaluation.plots" in ours
    cycles = [(m, d) for m in ours for d in graph[m] if reaches(graph, d, m)]
    assert not cycles
    assert not any(m.startswith("lossvo.report") for m in graph["lossvo.evaluation.plots"])
    evaluation = [m for m in graph if m.startswith("lossvo.evaluation")]
    assert "lossvo.evaluation.baselines" in evaluation  # a classical estimator: evaluation, not report
    assert not [(m, d) for m in evaluation for d in graph[m] if d.startswith("lossvo.report")]
    assert {"lossvo.report.tables", "lossvo.report.figures"} <= {
        m for m in graph if "lossvo.report.jobs" in graph[m]
    }


def test_the_report_builds_no_datamodule() -> None:
    modules = set(import_graph())
    for path in (SRC / "lossvo" / "report").glob("*.py"):
        tree = ast.parse(path.read_text())
        names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        names |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
        names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
        data = {m for m in imported(path, modules) if m.startswith("lossvo.data")}
        assert "instantiate" not in names, path.name
        formats = {"lossvo.data", "lossvo.data.kitti", "lossvo.data.sequence"}  # the formats, no datamodule
        assert data <= formats, (path.name, data)


def test_the_speed_section_follows_the_jobs_trajectories(sweep: Path, report: Path) -> None:
    """tables/speed.csv and its report.md section: per configuration and sequence outside the training
    split, the predicted over the true mean step length on the slowest and fastest fifth of the pairs,
    mean over seeds, recomputed here with numpy from the jobs' trajectories and the pose files."""
    with (report / "tables" / "speed.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert rows and "## Speed on the slowest and fastest stretches" in (report / "report.md").read_text()
    results = job_results(sweep)
    train = set(next(iter(results.values()))["data"]["train"])
    assert {row["sequence"] for row in rows}.isdisjoint(train)
    for row in rows:
        loss, sequence = row["configuration"].removeprefix("loss="), row["sequence"]
        jobs = [job for job in sweep.iterdir() if f"loss-{loss}+" in job.name]
        gt = read_pose_file(Path(results[(loss, 0)]["sequences"][sequence]["ground_truth"]))
        true = np.linalg.norm(np.linalg.solve(gt[:-1], gt[1:])[:, :3, 3], axis=1)
        slow = np.argsort(true, kind="stable")[: round(0.2 * len(true))]
        ratios = []
        for job in jobs:
            est = read_pose_file(job / "trajectories" / f"{sequence}.txt")
            predicted = np.linalg.norm(np.linalg.solve(est[:-1], est[1:])[:, :3, 3], axis=1)
            ratios.append(predicted[slow].mean() / true[slow].mean())
        assert float(row["slowest: true [m]"]) == pytest.approx(true[slow].mean(), rel=2e-3)
        assert float(row["slowest: predicted / true"].split(" ± ")[0]) == pytest.approx(
            np.mean(ratios), rel=5e-3
        )


def test_a_sweep_without_results_is_reported_and_exits_non_zero_naming_each_job(
    tmp_path: Path, capsys: pytest.CaptureFixture, caplog: pytest.LogCaptureFixture
) -> None:
    """Every job failed, or its files are broken: report.md still lists them, stderr names each job left out
    and why, and the command exits with status 2."""
    sweep = tmp_path / "sweep"
    jobs = {"0_loss-euler": '{"status": "failed", "error": "UserError: bad"}', "1_loss-quat": "{"}
    for name, status in jobs.items():
        (sweep / name / ".hydra").mkdir(parents=True)
        (sweep / name / ".hydra" / "config.yaml").write_text("selection: {monitor: val/score, mode: min}\n")
        (sweep / name / "status.json").write_text(status)
    with caplog.at_level("WARNING", logger="lossvo"):  # on stderr in a real process (logging to stderr)
        assert main([str(sweep), "--no-baselines", "--no-figures"]) == 2
    left = [r.getMessage() for r in caplog.records if r.getMessage().startswith("left out")]
    assert left[0] == "left out 0_loss-euler: failed: UserError: bad" and left[1].startswith(
        "left out 1_loss-quat"
    )
    last = capsys.readouterr().err.rstrip().splitlines()[-1]  # the command's own line comes last
    assert last.startswith(f"error: {sweep}: no job has results to report (2 left out")
    assert (sweep / "report" / "report.md").is_file()
