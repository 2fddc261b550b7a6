"""The report's table "trained on X, evaluated on Y": evaluations of the sweep's checkpoints on other
datasets, found under SWEEP/evaluations, pooled per configuration over seeds."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lossvo.evaluation import baselines
from lossvo.evaluation.job_folder import Overall
from lossvo.report.document import make_report
from test_report import data_record, entry, results_json, write_job


def write_evaluation(
    folder: Path, job: Path, layout: str, root: Path, rpe_trans: float, trained: Path
) -> None:
    """An evaluation's results.json: ``job``'s best checkpoint on ``layout`` data at ``root``, one
    sequence."""
    record = replace(data_record(root, ["s"], [], None), layout=layout, train_root=str(trained))
    scores = entry(rpe_trans, 0.01)
    results = replace(results_json(record, {"s": scores}), checkpoint=str(job / "checkpoints" / "best.ckpt"),
                      overall=Overall(["s"], scores))  # fmt: skip
    results.write(folder / "results.json")


def across_table(report: str) -> list[list[str]]:
    """The cells of the report's Across datasets table, its header first."""
    section = report.split("## Across datasets", 1)[1].splitlines()
    return [[c.strip() for c in line.strip("|").split("|")] for line in section if line.startswith("|")]


@pytest.fixture
def sweep(tmp_path: Path) -> Path:
    """Two configurations (euler, quat), each with two seeds; seed 0 and 1 of each evaluated on a
    TUM-layout dataset (RPE trans 0.2 / 0.4 m for euler, 0.3 / 0.3 m for quat); one evaluation of a
    foreign checkpoint."""
    sweep, kitti, tum = tmp_path / "sweep", tmp_path / "synthetic", tmp_path / "tum_synthetic"
    record = data_record(kitti, ["07"], [])
    for number, (loss, seed) in enumerate([("euler", 0), ("euler", 1), ("quat", 0), ("quat", 1)]):
        scores = {"07": entry(0.1, 0.01)}
        job = write_job(sweep, number, loss, {"train": ["00"], "val": ["07"]}, scores, record)
        job = job.rename(sweep / f"{number}_loss-{loss}+seed-{seed}")
        (job / ".hydra" / "overrides.yaml").write_text(f"- loss={loss}\n- seed={seed}\n")
        results = results_json(record, scores)
        replace(results, overall=Overall(["07"], scores["07"])).write(job / "results.json")
        rpe = {"euler": (0.2, 0.4), "quat": (0.3, 0.3)}[loss][seed]
        write_evaluation(sweep / "evaluations" / "tum" / str(number), job, "tum", tum, rpe, kitti)
    write_evaluation(
        sweep / "evaluations" / "foreign", tmp_path / "elsewhere" / "0_job", "tum", tum, 0.1, kitti
    )
    return sweep


def test_evaluations_on_other_data_make_the_across_datasets_table(sweep: Path, tmp_path: Path) -> None:
    report = make_report(sweep, tmp_path / "report", with_baselines=False, with_figures=False).read_text()
    table = across_table(report)
    assert table[0][:5] == ["network", "trained on", "evaluated on", "sequences", "n"]
    by_key = {(cells[0], cells[2]): cells for cells in table[2:]}
    assert len(by_key) == len(table) - 2 == 4
    euler_tum = by_key[("loss=euler", "tum: tum_synthetic")]
    assert euler_tum[1] == "kitti: synthetic" and euler_tum[4] == "2"
    assert euler_tum[6] == f"0.3 ± {np.std([0.2, 0.4], ddof=1):.2g}"  # mean ± sample std over the seeds
    assert by_key[("loss=quat", "tum: tum_synthetic")][6] == "0.3 ± 0"
    assert by_key[("loss=euler", "kitti: synthetic")][6] == "0.1 ± 0"  # the sweep's own evaluation
    assert "evaluation not used" in report and "foreign/results.json" in report and "of no job" in report
    assert (tmp_path / "report" / "tables" / "across_datasets.csv").is_file()


def test_a_moved_sweep_keeps_its_evaluations(sweep: Path, tmp_path: Path) -> None:
    """An archive unpacked elsewhere: the evaluations' checkpoints name the old folder; they are matched to
    the jobs by their folders' names (a checkpoint of no job of the sweep stays foreign)."""
    moved = sweep.rename(tmp_path / "unpacked")
    report = make_report(moved, tmp_path / "report", with_baselines=False, with_figures=False).read_text()
    assert len(across_table(report)) - 2 == 4 and "foreign/results.json" in report


def test_an_evaluation_on_other_sequences_of_the_training_data_is_a_row_not_a_seed(
    sweep: Path, tmp_path: Path
) -> None:
    kitti, job = tmp_path / "synthetic", next(sweep.glob("0_*"))
    write_evaluation(sweep / "evaluations" / "again" / "0", job, "kitti", kitti, 0.5, kitti)
    report = make_report(sweep, tmp_path / "report", with_baselines=False, with_figures=False).read_text()
    table = across_table(report)
    rows = {(cells[0], cells[2], cells[3]): cells for cells in table[2:]}
    assert rows[("loss=euler", "kitti: synthetic", "07")][4] == "2"  # the sweep's own, its two seeds
    again = rows[("loss=euler", "kitti: synthetic", "s")]
    assert again[4] == "1" and again[6] == "0.5"


def test_no_evaluations_no_section(sweep: Path, tmp_path: Path) -> None:
    for path in sorted((sweep / "evaluations").rglob("*"), reverse=True):
        path.unlink() if path.is_file() else path.rmdir()
    report = make_report(sweep, tmp_path / "report", with_baselines=False, with_figures=False).read_text()
    assert "## Across datasets" not in report
    assert not (tmp_path / "report" / "tables" / "across_datasets.csv").exists()


@pytest.mark.slow
def test_each_other_dataset_gets_its_baselines_and_the_rotation_against_zero_motion(tmp_path: Path) -> None:
    """A sweep trained on a KITTI-layout render, evaluated on a TUM-layout one: the baselines follow the
    TUM rows, computed on its sequence, and every row says how far its rotation lies below zero motion's."""
    from lossvo.data.synthetic.writer import generate

    kitti = generate(tmp_path / "kitti", ["00", "07"], frames=20, height=48, width=160, progress=False)
    tum = generate(tmp_path / "tum", ["07"], frames=20, layout="tum", scale=0.25, progress=False)
    name = "rgbd_dataset_freiburg1_synthetic_07"
    sweep = tmp_path / "sweep"
    record = data_record(kitti, ["07"], [])
    scores = {"07": entry(0.1, 0.01)}
    job = write_job(sweep, 0, "euler", {"train": ["00"], "val": ["07"]}, scores, record)
    replace(results_json(record, scores), overall=Overall(["07"], scores["07"])).write(job / "results.json")
    evaluated = replace(data_record(tum, [name], [], None), layout="tum", train_root=str(kitti))
    tum_scores = replace(entry(0.2, 0.001), rpe_scaled=entry(0.05, 0.001).rpe)
    results = results_json(evaluated, {name: tum_scores})
    tum_entry = replace(results.sequences[name], metric_scale=False)
    checkpoint = str(job / "checkpoints" / "best.ckpt")
    results = replace(
        results, sequences={name: tum_entry}, checkpoint=checkpoint, overall=Overall([name], tum_scores)
    )
    (sweep / "evaluations" / "tum").mkdir(parents=True)
    results.write(sweep / "evaluations" / "tum" / "results.json")
    report = make_report(sweep, tmp_path / "report", with_figures=False, n_jobs=1).read_text()
    table = across_table(report)
    header = table[0]
    rows = {
        cells[0]: dict(zip(header, cells, strict=True)) for cells in table[2:] if cells[2].startswith("tum")
    }
    assert next(iter(rows)) == "loss=euler" and set(rows) == {"loss=euler", *baselines.NAMES}
    zero, orb, network = rows[baselines.ZERO], rows[baselines.ORB], rows["loss=euler"]
    assert zero["rot below zero motion"] == "0%"
    expected = 1 - 0.001 / float(zero["RPE rot RMSE (rad)"])
    assert network["rot below zero motion"] == f"{expected:.0%}"
    assert (
        network["RPE trans RMSE, scale given (m)"] == "0.05"
        and network["translation read as"] == "scale given"
    )
    assert float(orb["RPE trans RMSE (m)"]) == pytest.approx(
        float(orb["RPE trans RMSE, scale given (m)"]), rel=1e-3
    )


@pytest.mark.slow
def test_a_network_trained_on_several_datasets_gets_baselines_on_each_set_of_sequences(
    tmp_path: Path,
) -> None:
    """A sweep trained on a car (KITTI layout) and a handheld camera (TUM layout), evaluated on two other
    TUM-layout sequences one at a time: each set of sequences is followed by baselines computed on it, the
    mean motion that of every training sequence of both sources."""
    from lossvo.data.synthetic.writer import generate
    from lossvo.evaluation.job_folder import MULTI_LAYOUT, SourceRecord

    car = generate(tmp_path / "car", ["00", "07"], frames=20, height=48, width=160, progress=False)
    hand = generate(
        tmp_path / "hand", ["00", "07", "08"], frames=20, layout="tum", scale=0.25, progress=False
    )
    name = {s: f"rgbd_dataset_freiburg1_synthetic_{s}" for s in ("00", "07", "08")}
    # rendered sources: the mix names their sequences by two digits, the TUM reader by its own names
    sources = {
        "car": SourceRecord("kitti", str(car), rendered=True),
        "hand": SourceRecord("tum", str(hand), rendered=True),
    }
    mix = replace(
        data_record(tmp_path, ["car/07"], [], ["car/00", "hand/00"]),
        layout=MULTI_LAYOUT, train_layout=MULTI_LAYOUT, sources=sources, train_sources=sources,
    )  # fmt: skip
    sweep, scores = tmp_path / "sweep", {"car/07": entry(0.1, 0.01)}
    job = write_job(sweep, 0, "euler", {"train": mix.train, "val": ["car/07"]}, scores, mix)
    replace(results_json(mix, scores), overall=Overall(["car/07"], scores["car/07"])).write(
        job / "results.json"
    )
    for s, rot in (("07", 0.001), ("08", 0.002)):
        evaluated = replace(mix, kind=None, root=str(hand), test=[name[s]], layout="tum", sources={})
        results = results_json(evaluated, {name[s]: entry(0.2, rot)})
        checkpoint = str(job / "checkpoints" / "best.ckpt")
        overall = Overall([name[s]], entry(0.2, rot))
        replace(results, checkpoint=checkpoint, overall=overall).write(
            sweep / "evaluations" / s / "results.json"
        )
    report = make_report(sweep, tmp_path / "report", with_figures=False, n_jobs=1).read_text()
    assert "no baselines" not in report and "baselines skipped" not in report
    table = across_table(report)
    rows = [dict(zip(table[0], cells, strict=True)) for cells in table[2:] if cells[2].startswith("tum")]
    assert [(r["network"], r["sequences"]) for r in rows] == [
        (network, name[s]) for s in ("07", "08") for network in ("loss=euler", *baselines.NAMES)
    ]
    zero = {r["sequences"]: r for r in rows if r["network"] == baselines.ZERO}
    training = [sequence.targets for sequence in baselines.training_sequences(mix)]
    assert len(training) == 2  # the car's sequence and the handheld one, each read in its layout
    for s, rot in (("07", 0.001), ("08", 0.002)):
        computed = baselines.compute_baselines(
            replace(mix, root=str(hand), layout="tum"), [name[s]], tmp_path
        )
        expected = computed[name[s]][baselines.ZERO].scores.rpe.rot_rad.rmse
        assert float(zero[name[s]]["RPE rot RMSE (rad)"]) == pytest.approx(expected, rel=1e-3)
        network = next(r for r in rows if r["sequences"] == name[s] and r["network"] == "loss=euler")
        assert network["rot below zero motion"] == f"{1 - rot / expected:.0%}"
