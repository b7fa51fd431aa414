"""Plain-text tables for the terminal: each column as wide as its widest cell, so a long
plugin name (a metric, a mapper) never runs into the next column."""

from __future__ import annotations

from collections.abc import Container, Iterable, Sequence


def columns(header: Sequence[str], rows: Iterable[Sequence[str]], right: Container[int] = ()) -> str:
    """The header and rows as lines, two spaces between columns. Cells are text already
    formatted; the columns whose index is in `right` (numbers) are right-aligned."""
    table = [list(header), *map(list, rows)]
    widths = [max(map(len, cells)) for cells in zip(*table)]

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return "\n".join(map(line, table))
