"""The axioms table: every ✓ is a hypothesis property that holds, every ✗ a counterexample found.

EXPECTED is the mathematics (see lossvo.geometry.axioms' notes for the closed forms); the property tests prove
each entry independently of lossvo.geometry.axioms' own sampling, and the last tests check that the generated
table and the copy of it in docs/losses.md say the same.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
import torch
from hypothesis import Phase, find, given, settings
from hypothesis import strategies as st

from lossvo import geometry as g
from lossvo.axioms import markdown_table
from lossvo.geometry import axioms

DOC = Path(__file__).resolve().parents[1] / "docs" / "losses.md"
TOL = axioms.TOLERANCE

FAILS = {
    "Euler": {"identity on rotations"},
    "Euler² (euler loss)": {"identity on rotations", "triangle inequality"},
    "quaternion, one sign": {"identity on rotations"},
    "quaternion, min over sign": set(),
    "quaternion² (quat loss)": {"triangle inequality"},
    "chordal": set(),
    "chordal² (chordal loss)": {"triangle inequality"},
    "geodesic": set(),
    "geodesic² (geodesic loss)": {"triangle inequality"},
}
BY_NAME = {d.name: d for d in axioms.DISTANCES}
CASES = [(name, axiom) for name in FAILS for axiom in axioms.AXIOMS]
HOLDS = [c for c in CASES if c[1] not in FAILS[c[0]]]
FAILING = [c for c in CASES if c[1] in FAILS[c[0]]]

unit = st.floats(-1.0, 1.0, allow_nan=False)
quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: sum(v * v for v in q) > 1e-2)


@st.composite
def rotations(draw: st.DrawFn) -> torch.Tensor:
    """(1, 3, 3) float64 rotation matrices from uniformly drawn quaternions."""
    q = torch.tensor(draw(quaternions), dtype=torch.float64)
    return g.quat_to_matrix(q / q.norm())[None]


@st.composite
def triples(draw: st.DrawFn) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, str]:
    """Rotations (x, y, z) and how y was chosen: at random, or the geodesic / coordinate midpoint."""
    R_x, R_z = draw(rotations()), draw(rotations())
    how = draw(st.sampled_from(["random", "geodesic midpoint", "coordinate midpoint"]))
    R_y = draw(rotations()) if how == "random" else axioms.geodesic_midpoint(R_x, R_z)
    return R_x, R_y, R_z, how


def write(d: axioms.Distance, *Rs: torch.Tensor) -> list[torch.Tensor]:
    return [d.representation.from_matrix(R) for R in Rs]


def violation(d: axioms.Distance, axiom: str, example: tuple) -> float:
    """How much ``example`` violates ``axiom`` for ``d`` (> TOL: violated)."""
    if axiom == "non-negativity":
        x, y = write(d, *example)
        return -d.fn(x, y).item()
    if axiom == "symmetry":
        x, y = write(d, *example)
        return abs(d.fn(x, y).item() - d.fn(y, x).item())
    if axiom == "identity on rotations":
        R_x, R_y = example
        (x,) = write(d, R_x)
        same = [d.fn(x, x), *(d.fn(x, a) for a in d.representation.aliases(x).values())]
        worst_same = max(v.item() for v in same)
        apart = g.so3_geodesic_distance(R_x, R_y).item() > 1e-3
        return max(worst_same, TOL - d.fn(*write(d, R_x, R_y)).item() if apart else 0.0)
    R_x, R_y, R_z, how = example
    x, y, z = write(d, R_x, R_y, R_z)
    if how == "coordinate midpoint":
        y = 0.5 * (x + z)
        if d.representation is not axioms.EULER:  # only Euler angles form a vector space
            return 0.0
    return (d.fn(x, z) - d.fn(x, y) - d.fn(y, z)).item()


def strategy(axiom: str) -> st.SearchStrategy:
    return triples() if axiom == "triangle inequality" else st.tuples(rotations(), rotations())


@pytest.mark.slow
@pytest.mark.parametrize(("name", "axiom"), HOLDS)
def test_axiom_holds(name: str, axiom: str) -> None:
    @given(strategy(axiom))
    def holds(example: tuple) -> None:
        assert violation(BY_NAME[name], axiom, example) <= TOL

    holds()


@pytest.mark.parametrize(("name", "axiom"), FAILING)
def test_axiom_fails(name: str, axiom: str) -> None:
    example = find(
        strategy(axiom),
        lambda ex: violation(BY_NAME[name], axiom, ex) > 1e-3,
        # No shrinking: any violation is a counterexample, the smallest one is not needed.
        settings=settings(max_examples=2000, database=None, phases=[Phase.generate]),
    )
    assert violation(BY_NAME[name], axiom, example) > 1e-3


def test_quaternion_min_sign_is_only_a_pseudo_metric_on_quaternions() -> None:
    q = g.matrix_to_quat(g.so3_exp(torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)))
    assert not torch.equal(q, -q)
    assert g.quat_distance(q, -q).item() == 0.0


def test_euler_distance_jumps_at_the_wrap() -> None:
    # Two rotations 0.002 rad apart whose wrapped yaw angles are ~2 pi apart.
    a = g.matrix_to_euler(g.euler_to_matrix(torch.tensor([math.pi - 1e-3, 0.0, 0.0], dtype=torch.float64)))
    b = g.matrix_to_euler(g.euler_to_matrix(torch.tensor([-math.pi + 1e-3, 0.0, 0.0], dtype=torch.float64)))
    assert g.euler_distance(a, b).item() == pytest.approx(2 * math.pi - 2e-3)


@pytest.mark.slow
def test_generated_table_agrees_with_the_mathematics() -> None:
    results = axioms.check_all()
    for name, verdicts in results.items():
        failing = {axiom for axiom, v in verdicts.items() if not v.holds}
        assert failing == FAILS[name], name


@pytest.mark.slow
def test_readme_shows_the_generated_table() -> None:
    table = markdown_table()
    readme = DOC.read_text(encoding="utf-8")
    block = re.search(r"<!-- axioms:begin -->\n(.*?)<!-- axioms:end -->", readme, flags=re.S)
    assert block is not None, "docs/losses.md lacks the <!-- axioms:begin/end --> block"
    assert block.group(1) == table, "docs/losses.md: axioms table stale, paste `python -m lossvo.axioms`"
