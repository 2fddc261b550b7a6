"""The one table renderer (lossvo.table_render), below every layer that writes a table: the data tables
and the axioms table render through it and read as the hand-built tables did."""

from __future__ import annotations

from lossvo import motion as motion_cli
from lossvo.data import motion
from lossvo.table_render import Rows, markdown


def hand_built(head: list[str], rows: list[list[str]]) -> str:
    """The markdown table as the motion, route-family and axioms tables were built by hand."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def test_markdown_reads_as_the_hand_built_table() -> None:
    head, rows = ["distance", "formula", "on SO(3)"], [["chordal", "‖R − R̂‖_F", "metric"], ["θ", "θ²", "—"]]
    assert markdown(Rows(head, rows)) == hand_built(head, rows)


def test_markdown_escapes_a_pipe_and_joins_lines() -> None:
    assert markdown(Rows(["a"], [["x | y\nz"]])) == "| a |\n|---|\n| x \\| y z |"


def test_motion_table_is_unchanged() -> None:
    rows = {"train": {c: 0.123456 * (i + 1) for i, c in enumerate(motion.COLUMNS)}}
    expected = hand_built(
        ["split / sequence", *motion.COLUMNS],
        [["train", "0", "0.247", "0.370", "0.494", "0.617", "0.741", "0.864", "98.8 %", "1.1111", "1.2346",
          "1.3580", "1.4815", "1.6049"]],
    )  # fmt: skip
    assert motion_cli.markdown(rows) == expected
