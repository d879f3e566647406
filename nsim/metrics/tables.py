"""Results tables: a list of rows (column name -> value) rendered as Markdown or fixed-width text.

Cells: floats with a fixed number of decimals (per column if asked; ``inf`` and ``nan`` spelled out),
ints and strings as they are, bools as yes/no. ``None`` and ``NotAvailable(reason)`` print as ``n/a``;
each distinct reason is listed once under the table, so a missing value is never a made-up number.
Numeric columns are right-aligned, the rest left-aligned.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

NA = "n/a"


@dataclass(frozen=True)
class NotAvailable:
    """A value that could not be computed, with the one-line reason (e.g. missing LPIPS weights)."""

    reason: str

    def __str__(self) -> str:
        return NA


def format_cell(value: object, decimals: int = 4) -> str:
    """One cell as text (module docstring)."""
    if value is None or isinstance(value, NotAvailable):
        return NA
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        value = float(value)
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.{decimals}f}"
    return str(value)


def _is_numeric(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _layout(
    rows: Sequence[Mapping[str, object]],
    columns: Sequence[str] | None,
    decimals: int | Mapping[str, int],
) -> tuple[list[str], list[list[str]], list[bool], list[str]]:
    """Columns, cell texts, right-alignment per column, and the distinct n/a reasons."""
    if columns is None:
        columns = list(dict.fromkeys(key for row in rows for key in row))
    columns = list(columns)
    if len(set(columns)) != len(columns):
        raise ValueError(f"table: duplicate column names in {columns}")
    if isinstance(decimals, Mapping):
        unknown = set(decimals) - set(columns)
        if unknown:
            raise ValueError(f"table: decimals given for unknown column(s) {sorted(unknown)}")
    known = set(columns)
    cells, reasons, numeric = [], [], [False] * len(columns)
    for r, row in enumerate(rows):
        extra = set(row) - known
        if extra:
            raise ValueError(f"table: row {r} has column(s) {sorted(extra)} not in {columns}")
        line = []
        for c, name in enumerate(columns):
            value = row.get(name)
            digits = decimals.get(name, 4) if isinstance(decimals, Mapping) else decimals
            line.append(format_cell(value, digits))
            numeric[c] |= _is_numeric(value)
            if isinstance(value, NotAvailable) and value.reason not in reasons:
                reasons.append(value.reason)
        cells.append(line)
    return columns, cells, numeric, reasons


def to_markdown(
    rows: Sequence[Mapping[str, object]],
    columns: Sequence[str] | None = None,
    decimals: int | Mapping[str, int] = 4,
) -> str:
    """A GitHub-flavoured Markdown table; columns default to the rows' keys in first-seen order.

    A row may leave a column out (printed n/a) but not name one outside ``columns`` (ValueError).
    """
    columns, cells, numeric, reasons = _layout(rows, columns, decimals)

    def line(parts: Sequence[str]) -> str:
        return "| " + " | ".join(p.replace("|", "\\|") for p in parts) + " |"

    out = [line(columns), "|" + "|".join("---:" if n else ":---" for n in numeric) + "|"]
    out += [line(row) for row in cells]
    if reasons:
        out += [""] + [f"- {NA}: {reason}" for reason in reasons]
    return "\n".join(out) + "\n"


def to_text(
    rows: Sequence[Mapping[str, object]],
    columns: Sequence[str] | None = None,
    decimals: int | Mapping[str, int] = 4,
) -> str:
    """A fixed-width text table (header, rule, rows; two spaces between columns), as ``to_markdown``."""
    columns, cells, numeric, reasons = _layout(rows, columns, decimals)
    widths = [max(len(text) for text in [name, *(row[c] for row in cells)]) for c, name in enumerate(columns)]

    def line(parts: Sequence[str]) -> str:
        return "  ".join(
            p.rjust(w) if n else p.ljust(w) for p, w, n in zip(parts, widths, numeric, strict=True)
        ).rstrip()

    out = [line(columns), "  ".join("-" * w for w in widths)] + [line(row) for row in cells]
    out += [f"{NA}: {reason}" for reason in reasons]
    return "\n".join(out) + "\n"
