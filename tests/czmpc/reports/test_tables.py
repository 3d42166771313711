"""czmpc.reports.tables: one layout for text and Markdown tables."""

from __future__ import annotations

import pytest

from czmpc.reports.tables import format_table

HEADER = ["scenario", "IAE [kW s]"]
ROWS = [["staircase", "301.2"], ["voltage_sag", "45.07"]]


def test_text_table_aligns_names_left_and_numbers_right() -> None:
    assert format_table(HEADER, ROWS).splitlines() == [
        "scenario     IAE [kW s]",
        "staircase         301.2",
        "voltage_sag       45.07",
    ]


def test_markdown_table_marks_right_aligned_columns() -> None:
    assert format_table(HEADER, ROWS, markdown=True).splitlines() == [
        "| scenario | IAE [kW s] |",
        "| --- | ---: |",
        "| staircase | 301.2 |",
        "| voltage_sag | 45.07 |",
    ]


def test_explicit_alignment() -> None:
    assert format_table(["a", "b"], [["x", "1"]], align="rl").splitlines() == ["a  b", "x  1"]


@pytest.mark.parametrize(("rows", "align", "match"), [
    ([["only one cell"]], None, r"row 0 has 1 cells; expected 2"),
    (ROWS, "lx", r"one 'l' or 'r' per column \(2\); got 'lx'"),
    (ROWS, "l", r"one 'l' or 'r' per column"),
])
def test_bad_shapes_are_refused_with_what_to_fix(rows: list[list[str]], align: str | None,
                                                 match: str) -> None:
    with pytest.raises(ValueError, match=match):
        format_table(HEADER, rows, align=align)
