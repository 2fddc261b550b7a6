"""``python -m lossvo.axioms``: which metric axioms each rotation distance satisfies, as the Markdown
table docs/losses.md shows (the checks: :mod:`lossvo.geometry.axioms`)."""

from __future__ import annotations

from lossvo.geometry.axioms import AXIOMS, DISTANCES, TOLERANCE, Verdict, check_all, classify
from lossvo.table_render import Rows, markdown


def markdown_table(results: dict[str, dict[str, Verdict]] | None = None) -> str:
    """The axioms table in Markdown: ✓/✗ per axiom, then what the distance is, then the failures."""
    results = check_all() if results is None else results
    rows, failures = [], []
    for d in DISTANCES:
        verdicts = results[d.name]
        marks = ["✓" if verdicts[a].holds else "✗" for a in AXIOMS]
        rows.append([d.name, d.formula, *marks, classify(verdicts), d.note])
        failures += [f"- {d.name}, {a}: {verdicts[a].evidence}" for a in AXIOMS if not verdicts[a].holds]
    table = markdown(Rows(["distance", "formula", *AXIOMS, "on SO(3)", "note"], rows))
    legend = (
        f"✓: holds on every sample (float64, slack {TOLERANCE:g}); ✗: violated, worst case found below. "
        "θ is the angle of the relative rotation."
    )
    return "\n".join([table, "", legend, "", "Counterexamples found:", "", *failures]) + "\n"


def main() -> None:
    """Print the axioms table (``python -m lossvo.axioms``)."""
    print(markdown_table(), end="")


if __name__ == "__main__":
    main()
