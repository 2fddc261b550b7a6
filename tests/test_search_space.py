"""The search space of lossvo's Optuna sweeper: Hydra's sweep syntax as Optuna distributions
(lossvo.training.search_space), and a bad one refused in one line naming its key."""

from __future__ import annotations

import pytest
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

from lossvo.console import UserError
from lossvo.training.search_space import parse


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("k=choice(1, 2.5, x, true)", CategoricalDistribution([1, 2.5, "x", True])),
        ("k=1,2,3", CategoricalDistribution([1, 2, 3])),
        ("k=interval(0.1, 10)", FloatDistribution(0.1, 10.0)),
        ("k=interval(1, 10)", FloatDistribution(1.0, 10.0)),  # Hydra reads an interval's ends as floats
        ("k=tag(log, interval(5.0, 2000.0))", FloatDistribution(5.0, 2000.0, log=True)),
        ("k=range(1, 9, 2)", IntDistribution(1, 9, step=2)),
        ("k=range(0.0, 1.0, 0.25)", FloatDistribution(0.0, 1.0, step=0.25)),
        ("k=shuffle(range(1, 4))", CategoricalDistribution([1, 2, 3])),
    ],
    ids=lambda case: case.split("=", 1)[1] if isinstance(case, str) else "",
)
def test_each_sweep_kind_becomes_its_distribution(override: str, expected: object) -> None:
    space, fixed = parse([override])
    assert space == {"k": expected} and fixed == {}


def test_plain_values_are_fixed_and_the_last_override_of_a_key_wins() -> None:
    """``hydra.sweeper.params`` first, then the command line: a fixed value given later takes the key
    out of the search space, a later sweep replaces an earlier one; the order of first mention kept."""
    space, fixed = parse(["loss.k=tag(log, interval(5.0, 2000.0))", "optimizer.lr=interval(1e-4, 3e-3)",
                          "loss=euler", "loss.k=100", "optimizer.lr=choice(0.001)"])  # fmt: skip
    assert space == {"optimizer.lr": CategoricalDistribution([0.001])}
    assert fixed == {"loss": "euler", "loss.k": "100"}


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("loss.k=interval(10, 1)", "loss.k: `low <= high` must hold"),
        ("loss.k=tag(log, interval(0.0, 1.0))", "loss.k: `low > 0` must hold for `log=True`"),
        ("loss.k=glob(*)", "loss.k: loss.k=glob(*) is not a search space (expected choice(...), interval"),
        ("loss.k=interval(1", "loss.k: no viable alternative at input 'interval(1' (in loss.k=interval(1)"),
        ("loss.k=choice(1, null)", "loss.k: TypeError while evaluating 'choice(1, null)'"),
    ],
    ids=["empty-interval", "log-of-zero", "glob", "unparsed", "null-choice"],
)
def test_a_bad_search_space_is_one_line_naming_the_key(override: str, message: str) -> None:
    with pytest.raises(UserError) as error:
        parse(["optimizer.lr=interval(1e-4, 3e-3)", override])
    assert str(error.value).startswith(message) and "\n" not in str(error.value)
