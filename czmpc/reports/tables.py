"""Tables for people: one formatter for terminal text and Markdown.

Cells arrive as strings (the caller formats numbers with their units in the header);
`format_table` only lays them out::

    format_table(["scenario", "IAE [kW s]"], [["staircase", "301.2"]])
    scenario   IAE [kW s]
    staircase       301.2

    format_table(["scenario", "IAE [kW s]"], [["staircase", "301.2"]], markdown=True)
    | scenario | IAE [kW s] |
    | --- | ---: |
    | staircase | 301.2 |
"""

from __future__ import annotations

from collections.abc import Sequence


def format_table(header: Sequence[str], rows: Sequence[Sequence[str]], *,
                 align: str | None = None, markdown: bool = False) -> str:
    """Lay out a table as aligned text columns or as a Markdown pipe table.

    Parameters
    ----------
    header :
        Column titles (with units in brackets where a column has one).
    rows :
        Cells, each row as long as ``header``.
    align :
        One letter per column, ``l`` (left) or ``r`` (right); default: the first
        column left, the others right (names, then numbers).
    markdown :
        Markdown pipe table instead of space-aligned text.

    Returns
    -------
    str
        The table, lines joined by newlines, without a trailing newline.

    Raises
    ------
    ValueError
        A row or ``align`` does not have one entry per column.
    """
    n = len(header)
    align = align if align is not None else "l" + "r" * (n - 1)
    if len(align) != n or set(align) - {"l", "r"}:
        raise ValueError(f"format_table: align must have one 'l' or 'r' per column ({n}); got {align!r}")
    for i, row in enumerate(rows):
        if len(row) != n:
            raise ValueError(f"format_table: row {i} has {len(row)} cells; expected {n} ({list(header)})")
    if markdown:
        marks = ["---:" if a == "r" else "---" for a in align]
        lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(marks) + " |"]
        lines += ["| " + " | ".join(row) + " |" for row in rows]
        return "\n".join(lines)
    widths = [max(len(str(cell)) for cell in column) for column in zip(header, *rows, strict=True)]

    def line(cells: Sequence[str]) -> str:
        parts = [c.rjust(w) if a == "r" else c.ljust(w) for c, w, a in zip(cells, widths, align, strict=True)]
        return "  ".join(parts).rstrip()

    return "\n".join([line(header), *(line(row) for row in rows)])


__all__ = ["format_table"]
