"""Tables on the terminal that never cut a header or a value.

A rich table is printed only when the console is wide enough for every cell at full
width (a terminal's width; elsewhere $COLUMNS, else rich's 80); otherwise (80 columns,
a log file, CI, `| tee`) each row becomes one plain line of `header=value` pairs, which
a narrow terminal may wrap but never truncates.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["print_table"]


def _fits(console: Any, table: Any) -> bool:
    from rich.measure import Measurement

    # Measured without the console's limit: the width every cell needs at full length.
    unbounded = console.options.update(width=1_000_000)
    width = Measurement.get(console, unbounded, table).maximum
    return bool(width <= console.width)


def plain_lines(title: str, columns: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """The plain layout: the title, then `first: header=value; ...` per row (empty cells
    left out)."""
    lines = [title] if title else []
    for row in rows:
        pairs = [f"{h}={v}" for h, v in zip(columns[1:], row[1:], strict=True) if v != ""]
        lines.append(f"{row[0]}: " + "; ".join(pairs) if pairs else str(row[0]))
    return lines


def print_table(
    console: Any,
    title: str,
    columns: Sequence[str],
    rows: Sequence[Sequence[str]],
    *,
    styles: Sequence[str | None] = (),
) -> None:
    """`rows` under `columns` as a rich table when it fits whole, else as plain lines.

    `styles` gives an optional rich style per row (tables only).
    """
    from rich.table import Table

    table = Table(title=title or None)
    for col in columns:
        table.add_column(col)
    for i, row in enumerate(rows):
        table.add_row(*row, style=styles[i] if i < len(styles) else None)
    if _fits(console, table):
        console.print(table)
        return
    for line in plain_lines(title, columns, rows):
        console.print(line, soft_wrap=True, markup=False, highlight=False)
