"""The report's claims without training: convergence epochs on hand-made curves, the verdict rule on
numbers built for each verdict, rotation weights and selection warnings from hand-made job configs, and
the claims of hand-made configurations (identified by their loss class, held-out sequences only, seeds
as the unit): known effects that 10 seeds decide and 3 cannot, cells that cannot outvote seeds, Holm's
correction over the other configurations.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf
from scipy.stats import t as scipy_t
from scipy.stats import wilcoxon

from lossvo.console import UserError
from lossvo.evaluation.job_folder import (
    DataRecord,
    KittiError,
    LossRecord,
    Overall,
    PoseErrors,
    Results,
    Scores,
    Statistics,
)
from lossvo.report import statistics
from lossvo.report.claims import (
    answer_rows,
    claims_csv_rows,
    claims_markdown,
    relative_interval_text,
    study_claims,
)
from lossvo.report.configurations import job_selection, job_weighting, selection_warning, weight_text
from lossvo.report.convergence import convergence
from lossvo.report.jobs import Curves, Job, trained_sequences
from lossvo.report.tables import NETWORK, Column, mean_std_text
from lossvo.table_render import csv_text

LOSSES = "lossvo.losses"


# --------------------------------------------------------------------------------------------------
# Convergence epoch
# --------------------------------------------------------------------------------------------------


def test_convergence_epoch_is_the_first_within_ten_percent_of_the_best() -> None:
    values = np.array([10.0, 5.0, 3.0, 2.1, 2.0, 2.05])  # best 2.0: within 10 % means <= 2.2
    assert statistics.convergence_epoch(np.arange(6), values) == 3
    assert statistics.convergence_epoch(np.arange(6) + 1, values) == 4  # returned in the given counting
    assert statistics.convergence_epoch(np.arange(6), values, tolerance=0.01) == 4  # <= 2.02


def test_convergence_epoch_boundary_nan_and_max_mode() -> None:
    assert statistics.convergence_epoch(np.arange(3), np.array([1.1, 1.5, 1.0])) == 0  # 1.1 <= 1.0 * 1.1
    assert statistics.convergence_epoch(np.arange(3), np.array([math.nan, 4.0, 1.0])) == 2
    assert statistics.convergence_epoch(np.arange(2), np.array([math.nan, math.nan])) is None
    assert statistics.convergence_epoch(np.arange(4), np.array([0.1, 0.5, 0.95, 1.0]), mode="max") == 2
    with pytest.raises(UserError, match="mode"):
        statistics.convergence_epoch(np.arange(2), np.ones(2), mode="lowest")


# --------------------------------------------------------------------------------------------------
# The verdict rule
# --------------------------------------------------------------------------------------------------


def lower_by(offsets: np.ndarray, n: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(claimed, other) of n pairs with distinct differences claimed - other = -offsets."""
    other = 1.0 + np.arange(n, dtype=np.float64)
    return other - offsets, other


def test_supported_when_lower_than_every_other_with_p_below_alpha() -> None:
    x, y = lower_by(0.1 * (1 + np.arange(10)))
    tests = [statistics.paired_test("euler", x, y), statistics.paired_test("quat", x, y + 0.5)]
    assert tests[0].n == 10 and tests[0].p_value == pytest.approx(2 / 2**10)  # exact: all one sign
    assert tests[0].mean == pytest.approx(x.mean()) and tests[0].versus_mean == pytest.approx(y.mean())
    assert statistics.verdict(tests) == statistics.SUPPORTED


def test_contradicted_when_another_is_lower_with_p_below_alpha() -> None:
    x, y = lower_by(0.1 * (1 + np.arange(10)))
    better = statistics.paired_test("quat", x, y)
    worse = statistics.paired_test("euler", y, x)  # the claimed one is higher on every pair
    assert worse.p_value == pytest.approx(2 / 2**10)
    assert statistics.verdict([better, worse]) == statistics.REFUTED
    assert statistics.verdict([worse]) == statistics.REFUTED


def test_not_distinguishable_for_mixed_signs_small_n_or_no_test() -> None:
    x, y = lower_by(np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6, 0.7, -0.8, 0.9, -0.05]))
    mixed = statistics.paired_test("quat", x, y)
    assert mixed.p_value > 0.5
    assert statistics.verdict([mixed]) == statistics.CANNOT_DECIDE
    assert (
        statistics.verdict([statistics.paired_test("quat", y, x)]) == statistics.CANNOT_DECIDE
    )  # other lower, p > 0.5
    few = statistics.paired_test("euler", np.array([1.0, 2.0, 3.0]), np.array([2.0, 4.0, 6.0]))
    assert few.claimed_lower and few.p_value == pytest.approx(0.25) == statistics.smallest_p(3)
    assert statistics.verdict([few]) == statistics.CANNOT_DECIDE
    assert statistics.verdict(
        [statistics.paired_test("euler", few_y := np.array([2.0, 4.0, 6.0]), few_y / 2)]
    ) == (statistics.CANNOT_DECIDE)  # the other is lower on all three pairs, but p = 0.25
    assert (
        statistics.verdict([statistics.paired_test("euler", np.array([]), np.array([]))])
        == statistics.CANNOT_DECIDE
    )
    assert statistics.verdict([]) == statistics.CANNOT_DECIDE


def test_smallest_p_and_combining_verdicts() -> None:
    assert [statistics.smallest_p(n) for n in (0, 1, 3, 5, 6)] == [1.0, 1.0, 0.25, 0.0625, 0.03125]
    s, c, n = statistics.SUPPORTED, statistics.REFUTED, statistics.CANNOT_DECIDE
    assert statistics.combine([s, s]) == s
    assert statistics.combine([s, n]) == n
    assert statistics.combine([s, c, n]) == c
    assert statistics.combine([]) == n


# --------------------------------------------------------------------------------------------------
# Rotation weights and selection metrics from hand-made job configs
# --------------------------------------------------------------------------------------------------


def job(loss: str, curves: dict | None = None, **config: object) -> Job:
    """A job with config ``loss._target_ = lossvo.losses.<loss>`` plus ``config`` (dotted keys)."""
    cfg = OmegaConf.create({"loss": {"_target_": f"{LOSSES}.{loss}"}})
    for key, value in config.items():
        OmegaConf.update(cfg, key.replace("__", "."), value, force_add=True)
    series = {k: (np.arange(len(v)), np.asarray(v, dtype=np.float64)) for k, v in (curves or {}).items()}
    return Job(Path(f"job_{loss}"), config=cfg, curves=Curves(series))


@pytest.mark.parametrize(
    ("loss", "k", "preset", "weight"),
    [
        ("EulerLoss", 100.0, "matched", 100.0),  # gain 1
        ("QuaternionLoss", 400.0, "matched", 100.0),  # gain 1/4
        ("QuaternionLoss", 14.0, "paper", 3.5),
        ("ChordalLoss", 153.0, "paper", 306.0),  # gain 2
    ],
)
def test_rotation_weight_is_k_times_the_small_angle_gain(
    loss: str, k: float, preset: str, weight: float
) -> None:
    j = job(loss, loss__k=k, weighting__preset=preset)
    assert job_weighting(j).weight == pytest.approx(weight)
    assert weight_text([job_weighting(j)] * 2) == f"{weight:.4g}"


def test_rotation_weight_of_an_unresolved_preset_k_without_a_preset_and_of_unknown_classes() -> None:
    unresolved = job(
        "ChordalLoss", loss__k="${no_such_resolver:x}", weighting__preset="matched", weighting__c=100.0
    )
    assert job_weighting(unresolved).k == pytest.approx(50.0)  # c / gain
    assert weight_text([job_weighting(unresolved)]) == "100"
    paper = job("QuaternionLoss", loss__k="${no_such_resolver:x}", weighting__preset="paper")
    assert weight_text([job_weighting(paper)]) == "3.5"
    no_preset = job("EulerLoss", loss__k=100.0)  # no weighting group
    assert job_weighting(no_preset).preset is None and weight_text([job_weighting(no_preset)]) == "100"
    unknown = Job(
        Path("x"), config=OmegaConf.create({"loss": {"_target_": "collections.OrderedDict", "k": 3.0}})
    )
    assert job_weighting(unknown).gain is None and weight_text([job_weighting(unknown)]) == "?"
    unsquared = job("ChordalLoss", loss__k=153.0, loss__squared=False, weighting__preset="paper")
    assert weight_text([job_weighting(unsquared)]).startswith("n/a")


def test_learned_rotation_weight_is_gain_times_exp_st_minus_sr_at_the_last_epoch() -> None:
    a = job("ChordalLoss", {"train/s_t": [0.0, 0.5], "train/s_r": [0.0, -0.2]}, weighting__preset="learned")
    b = job("ChordalLoss", {"train/s_t": [0.0, 0.3], "train/s_r": [0.0, 0.1]}, weighting__preset="learned")
    expected = np.array([2.0 * math.exp(0.7), 2.0 * math.exp(0.2)])
    assert job_weighting(a).weight == pytest.approx(expected[0])
    text = weight_text([job_weighting(a), job_weighting(b)])
    mean, std = (float(v) for v in text.removeprefix("learned: ").split(" ± "))
    assert mean == pytest.approx(expected.mean(), rel=1e-3)
    assert std == pytest.approx(expected.std(ddof=1), abs=0.05)  # two significant digits
    blind = job("ChordalLoss", weighting__preset="learned")  # no s_t, s_r logged
    assert weight_text([job_weighting(blind)]).startswith("learned: ?")


def test_selection_metric_is_the_configs_selection_monitor_and_mode() -> None:
    new = job("EulerLoss", selection__monitor="val/score", selection__mode="min",
              callbacks__model_checkpoint__monitor="${selection.monitor}")  # fmt: skip
    assert (job_selection(new.config).monitor, job_selection(new.config).mode) == ("val/score", "min")
    maximised = job("EulerLoss", selection__monitor="val/rot_err_rad", selection__mode="max")
    assert (job_selection(maximised.config).monitor, job_selection(maximised.config).mode) == (
        "val/rot_err_rad", "max")  # fmt: skip
    dangling = job("EulerLoss", callbacks__model_checkpoint__monitor="${selection.monitor}")
    with pytest.raises(UserError, match=r"selection\.monitor"):
        job_selection(dangling.config)


def column(label: str, *jobs: Job, results: list | None = None) -> Column:
    replicates = [f"seed={i}" for i in range(len(jobs))]
    return Column(label, NETWORK, replicates, results or [{} for _ in jobs], list(jobs))


def selected(loss: str, monitor: str, k: float = 100.0) -> Job:
    return job(loss, loss__k=k, selection__monitor=monitor, selection__mode="min")


def test_selection_warning_only_when_the_configurations_were_selected_by_different_metrics() -> None:
    score = [column("loss=euler", selected("EulerLoss", "val/score")),
             column("loss=quat", selected("QuaternionLoss", "val/score", 400.0))]  # fmt: skip
    assert selection_warning(score) is None
    mixed = [score[0], column("loss=quat", selected("QuaternionLoss", "val/loss", 400.0))]
    warning = selection_warning(mixed)
    assert warning is not None and warning.startswith("**Warning") and warning.endswith("**")
    assert "loss=euler: `val/score` (min)" in warning and "loss=quat: `val/loss` (min)" in warning
    own_loss = [column("loss=euler", selected("EulerLoss", "val/loss")),
                column("loss=quat", selected("QuaternionLoss", "val/loss", 400.0))]  # fmt: skip
    assert "its own loss value" in (selection_warning(own_loss) or "")
    same_loss = [column("lr=0.001", selected("EulerLoss", "val/loss")),
                 column("lr=0.01", selected("EulerLoss", "val/loss"))]  # fmt: skip
    assert selection_warning(same_loss) is None  # one loss, one k: val/loss is one metric


# --------------------------------------------------------------------------------------------------
# The claims of hand-made configurations
# --------------------------------------------------------------------------------------------------


def scores(value: float) -> Scores:
    """Scores whose every APE / RPE statistic is ``value`` (m or rad), no KITTI segment."""
    errors = PoseErrors(Statistics(*[value] * 6), Statistics(*[value] * 6))
    return Scores(errors, errors, KittiError(None, None))


def results(errors: dict[str, float]) -> dict[str, Scores]:
    """Per sequence, scores whose every error metric equals ``errors[sequence]``."""
    return {sequence: scores(value) for sequence, value in errors.items()}


def configuration(label: str, loss: str, errors: list[dict[str, float]], scores: list[list[float]]) -> Column:
    """A configuration of one job per seed: ``errors[seed]`` per sequence, ``scores[seed]`` per epoch."""
    jobs = [job(loss, {"val/score": s}) for s in scores]
    for j in jobs:
        j.results = record(["00", "01"])  # the training split its results.json records
    return column(label, *jobs, results=[results(e) for e in errors])


HELD_OUT = ("02", "03", "04", "05")
SEQUENCES = ["00", *HELD_OUT]
CANNOT_DECIDE_3 = (
    "3 seeds cannot decide: the smallest p an exact test can give with 3 paired seeds is 0.250 (6 seeds are "
    "needed for p < 0.05)."
)
FAST = [[5.0, 1.05, 1.0], [5.0, 2.0, 1.0], [4.0, 1.08, 1.0]]  # within 10 % at epochs 2, 3, 2 (1-based)
SLOW = [5.0, 3.0, 1.0]  # epoch 3


def sweep_columns(
    offset: float, alternate: bool = False, train_penalty: float = 5.0, seeds: int = 3
) -> list[Column]:
    """``seeds`` seeds, held-out sequences 02-05 (00 is in ``data.splits.train``). The ChordalLoss
    configuration (labelled ``loss=se3``) is :func:`chordal_step` off the EulerLoss one on each held-out
    sequence and ``train_penalty`` worse on 00; the EulerLoss configuration is (misleadingly) labelled
    ``loss=chordal``. Convergence: the ChordalLoss curves cycle through :data:`FAST` (epochs 2, 3, 2), the
    EulerLoss ones are :data:`SLOW` (epoch 3)."""
    base = [
        {s: 1.0 + 0.1 * i + 0.37 * seed + 0.011 * i * seed for i, s in enumerate(SEQUENCES)}
        for seed in range(seeds)
    ]
    ours = [
        {s: v + (train_penalty if s == "00" else chordal_step(offset, SEQUENCES.index(s), seed, alternate))
         for s, v in b.items()}
        for seed, b in enumerate(base)
    ]  # fmt: skip
    fast = [FAST[seed % len(FAST)] for seed in range(seeds)]
    return [
        configuration("loss=chordal", "EulerLoss", base, [SLOW] * seeds),
        configuration("loss=se3", "ChordalLoss", ours, fast),
    ]


def chordal_step(offset: float, j: int, seed: int, alternate: bool) -> float:
    """The ChordalLoss configuration's error minus the EulerLoss one's on held-out sequence j (1-4); all
    distinct (no ties), and with ``alternate`` of alternating sign from seed to seed."""
    return offset * (1 + 0.1 * j + 0.03 * seed) * (-1.0 if alternate and seed % 2 else 1.0)


@pytest.mark.parametrize(
    ("offset", "alternate", "seeds", "expected"),
    [(-0.5, False, 10, statistics.SUPPORTED), (0.5, False, 10, statistics.REFUTED),
     (-0.5, True, 10, statistics.CANNOT_DECIDE), (-0.5, False, 3, statistics.CANNOT_DECIDE)],
)  # fmt: skip
def test_error_claim_pairs_seed_means_over_held_out_sequences_of_the_chordal_loss_class(
    offset: float, alternate: bool, seeds: int, expected: str
) -> None:
    columns = sweep_columns(offset, alternate, seeds=seeds)
    a, _ = study_claims(columns, convergence(columns), SEQUENCES)
    assert a.configuration == "loss=se3"  # by loss._target_, not by label
    assert a.verdict == expected
    # each seed's mean difference over the held-out sequences (00 is trained on: left out)
    d = np.array(
        [np.mean([chordal_step(offset, j, s, alternate) for j in range(1, 5)]) for s in range(seeds)]
    )
    for q in a.quantities:
        (t,) = q.tests
        assert t.versus == "loss=chordal" and t.n == seeds
        assert t.mean_diff == pytest.approx(d.mean()) and t.sd_diff == pytest.approx(d.std(ddof=1))
        assert t.p_value == pytest.approx(wilcoxon(d, method="exact").pvalue, rel=1e-12)
        assert t.holm_p == t.p_value  # a family of one
        assert q.verdict == expected
        (cells,) = q.secondary
        assert cells.n == seeds * len(HELD_OUT)
    if not alternate:
        assert a.quantities[0].tests[0].p_value == pytest.approx(2 / 2**seeds)  # exact: all of one sign
    text = claims_markdown([a])
    if seeds == 3:
        assert a.undecidable == [CANNOT_DECIDE_3]
        assert f"**Verdict: {expected}.** 3 seeds cannot decide: " in text
    else:
        assert a.undecidable == [] and "seeds cannot decide" not in text.split("**Verdict")[1]
    theirs = columns[1].results  # mean over held-out sequences per seed, then mean ± std over seeds
    per_seed = np.array([np.mean([r[s].rpe.trans.rmse for s in HELD_OUT]) for r in theirs])
    cell = a.measured["loss=se3"]["RPE trans RMSE [m]"]
    assert (cell.n, cell.mean, cell.std) == (
        seeds,
        pytest.approx(per_seed.mean()),
        pytest.approx(per_seed.std(ddof=1)),
    )


def noisy_columns(
    effects: dict[str, float], seeds: int, sequences: int = 4, noise: float = 0.05
) -> list[Column]:
    """ChordalLoss (``loss=chordal``) and one configuration per entry of ``effects`` (``loss=<name>``, an
    EulerLoss): on ``sequences`` held-out sequences 02, 03, ... (00 is trained on), configuration c's error
    on (seed, sequence) is base + effects[c] + a seed-level noise of SD ``noise`` (the same on every
    sequence of the seed); the chordal one has effect 0. Fixed numpy seed."""
    rng = np.random.default_rng(7)
    names = ["00", *(f"{i:02d}" for i in range(2, 2 + sequences))]
    base = 1.0 + 0.1 * np.arange(len(names))
    out = []
    for label, effect in {"chordal": 0.0, **effects}.items():
        shift = effect + noise * rng.standard_normal(seeds)
        errors = [{s: base[i] + shift[seed] for i, s in enumerate(names)} for seed in range(seeds)]
        loss = "ChordalLoss" if label == "chordal" else "EulerLoss"
        out.append(configuration(f"loss={label}", loss, errors, [SLOW] * seeds))
    return out


def held_out_means(column: Column, sequences: list[str]) -> np.ndarray:
    """(seeds,) each seed's mean RPE translation RMSE over ``sequences``."""
    return np.array([np.mean([r[s].rpe.trans.rmse for s in sequences]) for r in column.results])


@pytest.mark.parametrize("seeds", [10, 3])
def test_a_known_effect_is_supported_with_ten_seeds_and_cannot_be_decided_with_three(seeds: int) -> None:
    columns = noisy_columns({"euler": 0.1}, seeds)  # chordal = euler - 0.1 + noise (SD 0.05 each)
    sequences = sorted({s for r in columns[0].results for s in r})
    a, _ = study_claims(columns, convergence(columns), sequences)
    d = held_out_means(columns[0], sequences[1:]) - held_out_means(columns[1], sequences[1:])
    t = a.quantities[0].tests[0]
    assert t.n == seeds and t.mean_diff == pytest.approx(d.mean())
    low, high = scipy_t.interval(0.95, seeds - 1, loc=d.mean(), scale=d.std(ddof=1) / math.sqrt(seeds))
    assert (t.ci_low, t.ci_high) == (pytest.approx(low, rel=1e-12), pytest.approx(high, rel=1e-12))
    assert t.relative == pytest.approx(d.mean() / held_out_means(columns[1], sequences[1:]).mean())
    text = claims_markdown([a])
    if seeds == 10:
        assert a.verdict == statistics.SUPPORTED and t.p_value < 0.05 and low < high < 0
        assert "**Verdict: supported.**" in text
        answer = [r for r in answer_rows([a]).rows if r[1] == "RPE trans RMSE [m]"]
        cells = {label: mean_std_text(a.measured[label]["RPE trans RMSE [m]"]) for label in a.measured}
        assert answer == [["", "RPE trans RMSE [m]", cells["loss=chordal"], "loss=euler", cells["loss=euler"],
                           relative_interval_text(t), 10, "supported", ""]]  # fmt: skip
    else:
        assert a.verdict == statistics.CANNOT_DECIDE
        verdict = "**Verdict: cannot decide at this n.**"
        assert f"{verdict} {CANNOT_DECIDE_3}" in text


def test_cells_that_would_decide_do_not_when_the_seed_means_cannot() -> None:
    columns = noisy_columns({"euler": 0.1}, seeds=3, sequences=13)  # 3 seeds x 13 sequences = 39 cells
    sequences = sorted({s for r in columns[0].results for s in r})
    a, _ = study_claims(columns, convergence(columns), sequences, margin=0.01)  # ~6 %: no equivalence
    for q in a.quantities:
        (cells,) = q.secondary
        assert cells.n == 39 and cells.p_value < 1e-6  # every cell lower: the cells alone would "decide"
        (t,) = q.tests
        assert t.n == 3 and t.p_value >= statistics.smallest_p(3) == 0.25
    assert a.verdict == statistics.CANNOT_DECIDE
    assert a.undecidable == [CANNOT_DECIDE_3]
    text = claims_markdown([a])
    assert "Secondary: (seed, sequence) cells share a network; indicative only (never decides" in text


def test_another_configuration_clearly_lower_contradicts_with_holm_over_the_others() -> None:
    columns = noisy_columns({"euler": 0.1, "quat": -0.1}, seeds=10)  # quat clearly lower than chordal
    sequences = sorted({s for r in columns[0].results for s in r})
    a, _ = study_claims(columns, convergence(columns), sequences)
    assert a.verdict == statistics.REFUTED
    q = a.quantities[0]
    assert [t.versus for t in q.tests] == ["loss=euler", "loss=quat"]
    ours = held_out_means(columns[0], sequences[1:])
    p = []
    for t, other in zip(q.tests, columns[1:], strict=True):
        d = ours - held_out_means(other, sequences[1:])
        p.append(wilcoxon(d, method="exact").pvalue)
        assert t.p_value == pytest.approx(p[-1], rel=1e-12)
    first, second = sorted(p)  # Holm over the family of two: 2 p_(1), max(2 p_(1), p_(2))
    expected = {first: min(1.0, 2 * first), second: min(1.0, max(2 * first, second))}
    assert [t.holm_p for t in q.tests] == [pytest.approx(expected[x], rel=1e-12) for x in p]
    assert q.tests[1].mean_diff > 0 and q.tests[1].holm_p < 0.05
    assert all(t.seeds_needed >= statistics.min_seeds(2) == 7 for t in q.tests)


def test_convergence_claim_pairs_epochs_by_seed_and_cannot_reach_p_below_alpha_with_three() -> None:
    columns = sweep_columns(-0.5)
    items = convergence(columns)
    by_label = {c.label: c for c in items}
    assert by_label["loss=se3"].epochs == [2, 3, 2] and by_label["loss=chordal"].epochs == [3, 3, 3]
    assert by_label["loss=se3"].cell().mean == pytest.approx(7 / 3)
    _, b = study_claims(columns, items, SEQUENCES)
    (t,) = b.quantities[0].tests
    assert (t.n, t.mean, t.versus_mean) == (3, pytest.approx(7 / 3), 3.0)
    # d = (-1, 0, -1): a zero, so the sign-flip test: |sum| >= 2 in 4 of the 8 sign patterns
    assert t.method == statistics.SIGN_FLIP and t.p_value == 0.5 >= statistics.smallest_p(3) == 0.25
    assert b.verdict == statistics.CANNOT_DECIDE
    text = claims_markdown(study_claims(columns, items, SEQUENCES))
    assert text.count(f"**Verdict: cannot decide at this n.** {CANNOT_DECIDE_3}") == 2  # (a) and (b)


def test_convergence_claim_with_ten_seeds_is_an_exact_sign_flip_test_with_ties() -> None:
    columns = sweep_columns(-0.5, seeds=10)
    _, b = study_claims(columns, convergence(columns), SEQUENCES)
    (t,) = b.quantities[0].tests  # d = (-1, 0, -1) repeated: 7 of -1 and 3 zeros
    assert t.n == 10 and t.method == statistics.SIGN_FLIP
    assert t.p_value == pytest.approx(2 * 2**3 / 2**10)  # the two patterns of the seven, times the zeros'
    assert b.verdict == statistics.SUPPORTED


def test_claims_cannot_be_tested_without_a_chordal_configuration() -> None:
    columns = [c for c in sweep_columns(-0.5) if c.label == "loss=chordal"]  # the EulerLoss one
    found = study_claims(columns, convergence(columns), ["00", "02"])
    assert all(c.untested and "no chordal configuration" in c.untested for c in found)
    assert claims_markdown(found).count("Cannot be tested: the sweep has no chordal configuration") == 2
    rows = list(csv.DictReader(io.StringIO(csv_text(claims_csv_rows(found)))))
    assert [r["verdict"] for r in rows] == ["cannot be tested"] * 2


def test_the_claimed_loss_is_a_setting_named_in_the_rule() -> None:
    columns = sweep_columns(-0.5, seeds=10)
    a, b = study_claims(columns, convergence(columns), SEQUENCES, claimed_loss="EulerLoss")
    assert (a.configuration, b.configuration) == ("loss=chordal", "loss=chordal")  # the EulerLoss one
    assert a.verdict == statistics.REFUTED  # the ChordalLoss configuration is lower on every seed
    text = claims_markdown([a, b])
    assert "`loss._target_` class `EulerLoss`" in text
    assert a.statement == "the euler loss gives the lowest errors"
    assert "chordal" not in text.replace("loss=chordal", "")  # named by the claimed loss, not the study's
    assert answer_rows([a, b], "EulerLoss").header[2] == "euler"  # the claimed configuration's column
    default = study_claims(columns, convergence(columns), SEQUENCES)
    assert "`loss._target_` class `ChordalLoss`" in claims_markdown(default)
    assert default[0].statement == "the chordal loss gives the lowest errors"
    absent = study_claims(columns, convergence(columns), SEQUENCES, claimed_loss="QuatLoss")
    assert all(c.untested and "loss._target_ QuatLoss" in c.untested for c in absent)
    assert all("the sweep has no quat configuration" in c.untested for c in absent if c.untested)


def test_claims_csv_has_a_row_per_test_and_one_per_claim() -> None:
    columns = sweep_columns(-0.5)
    found = study_claims(columns, convergence(columns), SEQUENCES)
    rows = list(csv.DictReader(io.StringIO(csv_text(claims_csv_rows(found)))))
    assert len(rows) == 3 + 1 + 1 + 1  # three error metrics + overall, the epochs + overall
    overall = {r["claim"]: r for r in rows if r["versus"] == "all"}
    assert {c: r["verdict"] for c, r in overall.items()} == {
        "the chordal loss gives the lowest errors": "cannot decide at this n",
        "it converges fastest": "cannot decide at this n"}  # fmt: skip
    assert all(r["note"].startswith("3 seeds cannot decide") for r in overall.values())
    epochs = next(r for r in rows if r["quantity"] == "convergence epoch")
    assert float(epochs["smallest_p"]) == 0.25 and int(epochs["n_seeds"]) == 3
    assert float(epochs["mean_difference"]) == pytest.approx(-2 / 3) and epochs["secondary_cells"] == ""
    assert float(epochs["p_value"]) == float(epochs["holm_p"]) == 0.5
    errors = next(r for r in rows if r["quantity"] == "RPE trans RMSE [m]")
    d = np.array([np.mean([chordal_step(-0.5, j, s, False) for j in range(1, 5)]) for s in range(3)])
    assert float(errors["mean_difference"]) == pytest.approx(d.mean())
    assert int(errors["seeds_needed"]) == statistics.seeds_needed(d.mean(), d.std(ddof=1))
    assert int(errors["secondary_cells"]) == 12 and float(errors["secondary_p"]) == pytest.approx(2 / 2**12)


def record(train: list[str], root: str = "/data/kitti") -> Results:
    """A results.json recording evaluation on ``root`` of a network trained on ``train`` of /data/kitti."""
    data = DataRecord(None, root, [], [], "/data/kitti", train)
    overall = Overall([], note="no sequence with ground truth: no metrics")
    return Results(None, LossRecord("EulerLoss", 100.0), "none", 1, 3, False, data, {}, overall)


def recorded(column: Column, train: list[str], root: str = "/data/kitti") -> Column:
    """``column`` with every job's results.json recording ``train`` as its training split."""
    for j in column.jobs:
        j.results = record(train, root)
    return column


def test_held_out_sequences_come_from_the_training_split_that_results_json_records() -> None:
    j = job("EulerLoss", data__train=["00", "01"])  # the config's data.splits.train is not what counts
    j.results = record(["02"])
    assert trained_sequences(j) == {"02"}
    j.results = record(["02"], root="/data/other")  # evaluated on other data: none of it was trained on
    assert trained_sequences(j) == set()
    columns = [recorded(c, ["00", "02"]) for c in sweep_columns(-0.5)]
    a, _ = study_claims(columns, convergence(columns), SEQUENCES)
    assert a.scope == "On the sequences outside the training split: 03, 04, 05."
    d = np.array([np.mean([chordal_step(-0.5, j, s, False) for j in range(2, 5)]) for s in range(3)])
    for q in a.quantities:
        (t,), (cells,) = q.tests, q.secondary
        assert t.n == 3 and t.mean_diff == pytest.approx(d.mean())  # each seed's mean over 03-05
        assert cells.n == 3 * 3


def test_the_forest_plot_draws_claim_a_and_nothing_without_it(tmp_path: Path) -> None:
    from lossvo.report.figures import forest_rows, plot_forest

    columns = noisy_columns({"euler": 0.1, "quat": 0.0}, seeds=10)
    sequences = sorted({s for r in columns[0].results for s in r})
    claims = study_claims(columns, convergence(columns), sequences)
    rows = forest_rows(claims[0], {c.label: c for c in columns})
    assert [label for label, _ in rows] == ["loss=chordal", "loss=euler", "loss=quat"]
    seeds = rows[0][1]["RPE trans RMSE [m]"]
    assert list(seeds.values()) == pytest.approx(list(held_out_means(columns[0], sequences[1:])))
    assert plot_forest(claims, columns, tmp_path / "forest.png")
    assert (tmp_path / "forest.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    untested = [c for c in sweep_columns(-0.5) if c.label == "loss=chordal"]
    assert not plot_forest(
        study_claims(untested, convergence(untested), ["00", "02"]), untested, tmp_path / "x.png"
    )
    assert not (tmp_path / "x.png").exists()
