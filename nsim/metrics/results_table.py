"""Results tables: a list of rows (column name -> value) rendered as Markdown, text, LaTeX, CSV, JSON.

Cells: floats with a fixed number of decimals (per column if asked; ``inf`` and ``nan`` spelled out),
ints and strings as they are, bools as yes/no. ``None`` and ``NotAvailable(reason)`` print as ``n/a``;
each distinct reason is listed once under the table, so a missing value is never a made-up number.
Numeric columns are right-aligned, the rest left-aligned.

``to_markdown`` / ``to_text`` render bare rows. A ``Table`` adds what a paper table needs: a title,
``Column``s that say whether higher or lower is better (an arrow in the header: ``PSNR ↑``,
LaTeX ``PSNR $\\uparrow$``), notes (e.g. "depth metrics without median scaling"), summary rows
ruled off at the bottom (``footer_rows``), and optionally the best value per column in bold. With
two or more distinct n/a reasons each n/a cell carries a numbered marker (``n/a¹``, LaTeX
``n/a$^{1}$``) pointing at its reason. ``Table.write_all(dir, stem)`` writes ``stem.md``,
``stem.tex`` (booktabs), ``stem.csv`` (full precision, n/a as ``n/a``) and ``stem.json`` (lossless:
``Table.from_json`` reads it back).
"""

from __future__ import annotations

import csv
import io
import json
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

NA = "n/a"
DIRECTIONS = ("higher", "lower")
ARROWS = {"higher": "↑", "lower": "↓"}
LATEX_ARROWS = {"higher": r"$\uparrow$", "lower": r"$\downarrow$"}


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


# --------------------------------------------------------------------------------------
# Table: a titled table with metric directions, notes and several output formats
# --------------------------------------------------------------------------------------

_SUPERSCRIPTS = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
_LATEX_TEXT = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
               "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}
_LATEX_MATH = {"δ": r"\delta", "Δ": r"\Delta", "²": "^2", "³": "^3", "↑": r"\uparrow", "↓": r"\downarrow",
               "−": "-", "<": "<", ">": ">", "|": "|", "µ": r"\mu", "°": r"^\circ", "±": r"\pm",
               "≤": r"\leq", "≥": r"\geq", "×": r"\times"}


def latex_escape(text: str) -> str:
    """Plain text as LaTeX: special characters escaped, Greek letters, super-scripts and symbols
    such as ``δ < ² ³ ↑ ↓ −`` set in math mode (adjacent ones share one ``$...$``).
    """
    parts: list[tuple[bool, str]] = []
    for ch in text:
        math_mode = ch in _LATEX_MATH
        piece = _LATEX_MATH[ch] if math_mode else _LATEX_TEXT.get(ch, ch)
        if parts and parts[-1][0] == math_mode:
            parts[-1] = (math_mode, parts[-1][1] + piece)
        else:
            parts.append((math_mode, piece))
    return "".join(f"${p}$" if m else p for m, p in parts)


@dataclass(frozen=True)
class Column:
    """A table column: ``name`` is the row key and the header; ``direction`` "higher" or "lower" is
    better (an arrow in the header; None: no arrow, never bold); ``decimals`` for floats; ``latex``
    a LaTeX header to use instead of the escaped name (without the arrow).
    """

    name: str
    direction: str | None = None
    decimals: int = 4
    latex: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Column.name: expected a non-empty string, got {self.name!r}")
        if self.direction is not None and self.direction not in DIRECTIONS:
            raise ValueError(f"Column.direction ({self.name}): expected one of {DIRECTIONS} or None, "
                             f"got {self.direction!r}")
        if isinstance(self.decimals, bool) or not isinstance(self.decimals, int) or self.decimals < 0:
            raise ValueError(f"Column.decimals ({self.name}): expected an int >= 0, got {self.decimals!r}")

    @property
    def header(self) -> str:
        return f"{self.name} {ARROWS[self.direction]}" if self.direction else self.name

    @property
    def latex_header(self) -> str:
        text = self.latex if self.latex is not None else latex_escape(self.name)
        return f"{text} {LATEX_ARROWS[self.direction]}" if self.direction else text


def _json_cell(value: object) -> Any:
    if isinstance(value, NotAvailable):
        return {"not_available": value.reason}
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        value = float(value)
        return value if math.isfinite(value) else {"float": format_cell(value)}
    raise TypeError(f"table cell {value!r}: expected a number, string, bool, None or NotAvailable")


def _from_json_cell(value: Any) -> object:
    if isinstance(value, dict):
        if set(value) == {"not_available"}:
            return NotAvailable(str(value["not_available"]))
        if set(value) == {"float"}:
            return float(value["float"])
        raise ValueError(f"table JSON: unknown cell object {value!r}")
    return value


@dataclass(frozen=True)
class Table:
    """A paper table (module docstring). ``rows`` map column names to cells; a row may leave a
    column out (n/a) but not name an unknown one (ValueError). ``footer_rows``: the last rows are
    summaries (mean, median), ruled off and never bold. ``label``: LaTeX ``\\label`` (optional).
    """

    title: str
    columns: tuple[Column, ...]
    rows: tuple[Mapping[str, object], ...]
    notes: tuple[str, ...] = ()
    footer_rows: int = 0
    bold_best: bool = False
    label: str | None = None
    _reasons: tuple[str, ...] = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        columns = tuple(c if isinstance(c, Column) else Column(str(c)) for c in self.columns)
        names = [c.name for c in columns]
        if len(set(names)) != len(names):
            raise ValueError(f"Table {self.title!r}: duplicate column names in {names}")
        rows = tuple(dict(r) for r in self.rows)
        for k, row in enumerate(rows):
            extra = set(row) - set(names)
            if extra:
                raise ValueError(f"Table {self.title!r}: row {k} has column(s) {sorted(extra)} not in {names}")
            for value in row.values():
                _json_cell(value)  # TypeError for cells no format can hold
        if not 0 <= self.footer_rows <= len(rows):
            raise ValueError(f"Table {self.title!r}: footer_rows {self.footer_rows} not in [0, {len(rows)}]")
        reasons = list(dict.fromkeys(v.reason for r in rows for v in r.values() if isinstance(v, NotAvailable)))
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "rows", rows)
        object.__setattr__(self, "notes", tuple(self.notes))
        object.__setattr__(self, "_reasons", tuple(reasons))

    # ---- cells -------------------------------------------------------------------------

    def _numeric(self) -> list[bool]:
        return [any(_is_numeric(r.get(c.name)) for r in self.rows) for c in self.columns]

    def _best(self) -> dict[str, float]:
        """Best rounded value per column with a direction, over the body rows."""
        best = {}
        body = self.rows[: len(self.rows) - self.footer_rows]
        for c in self.columns:
            if c.direction is None:
                continue
            values = [round(float(r[c.name]), c.decimals) for r in body
                      if _is_numeric(r.get(c.name)) and math.isfinite(float(r[c.name]))]
            if values:
                best[c.name] = max(values) if c.direction == "higher" else min(values)
        return best

    def _cells(self, bold: bool, na: str, bold_fmt: str) -> list[list[str]]:
        """Cell texts; ``na`` formats an n/a marker number (``{}``), ``bold_fmt`` a bold value."""
        best = self._best() if bold else {}
        body_n = len(self.rows) - self.footer_rows
        out = []
        for k, row in enumerate(self.rows):
            line = []
            for c in self.columns:
                value = row.get(c.name)
                if isinstance(value, NotAvailable) and len(self._reasons) > 1:
                    text = na.format(self._reasons.index(value.reason) + 1)
                else:
                    text = format_cell(value, c.decimals)
                if (k < body_n and c.name in best and _is_numeric(value) and math.isfinite(float(value))
                        and round(float(value), c.decimals) == best[c.name]):
                    text = bold_fmt.format(text)
                line.append(text)
            out.append(line)
        return out

    def _reason_lines(self, marker: str) -> list[str]:
        if len(self._reasons) == 1:
            return [f"{NA}: {self._reasons[0]}"]
        return [f"{NA}{marker.format(k + 1)}: {reason}" for k, reason in enumerate(self._reasons)]

    # ---- formats -----------------------------------------------------------------------

    def to_markdown(self, bold_best: bool | None = None) -> str:
        """A ``### title`` heading, a GitHub-flavoured table (Markdown has no inner rules: footer rows
        follow the body with their first cell in italics), then notes and n/a reasons as a list.
        """
        bold = self.bold_best if bold_best is None else bold_best
        cells = [[_superscript_markers(t) for t in line] for line in self._cells(bold, "n/a{}", "**{}**")]

        def line(parts: Sequence[str]) -> str:
            return "| " + " | ".join(p.replace("|", "\\|") for p in parts) + " |"

        numeric = self._numeric()
        out = [f"### {self.title}", "", line([c.header for c in self.columns]),
               "|" + "|".join("---:" if n else ":---" for n in numeric) + "|"]
        body_n = len(self.rows) - self.footer_rows
        for k, row in enumerate(cells):
            if k >= body_n and row and not numeric[0]:
                row = [f"*{row[0]}*", *row[1:]]
            out.append(line(row))
        extra = [f"- {n}" for n in self.notes] + [f"- {_superscript_markers(t)}" for t in self._reason_lines("{}")]
        if extra:
            out += ["", *extra]
        return "\n".join(out) + "\n"

    def to_text(self) -> str:
        """Fixed-width text: title, header with arrows, rule, rows (footer after a rule), notes."""
        cells = [[_superscript_markers(t) for t in line] for line in self._cells(False, "n/a{}", "{}")]
        headers = [c.header for c in self.columns]
        widths = [max(len(t) for t in [h, *(r[k] for r in cells)]) for k, h in enumerate(headers)]
        numeric = self._numeric()

        def line(parts: Sequence[str]) -> str:
            return "  ".join(p.rjust(w) if n else p.ljust(w)
                             for p, w, n in zip(parts, widths, numeric, strict=True)).rstrip()

        rule = "  ".join("-" * w for w in widths)
        body_n = len(self.rows) - self.footer_rows
        out = [self.title, line(headers), rule] + [line(r) for r in cells[:body_n]]
        if self.footer_rows:
            out += [rule] + [line(r) for r in cells[body_n:]]
        out += list(self.notes) + [_superscript_markers(t) for t in self._reason_lines("{}")]
        return "\n".join(out) + "\n"

    def to_latex(self, bold_best: bool | None = None) -> str:
        """A ``table`` float with a booktabs ``tabular`` (text columns ``l``, numeric ``r``), the
        title as caption, notes and n/a reasons in a footnote-sized paragraph under the tabular.
        """
        bold = self.bold_best if bold_best is None else bold_best
        raw = self._cells(bold, "n/a$^{{{}}}$", "\x00{}\x01")

        def tex(text: str) -> str:
            if text.startswith("n/a$^"):
                return text
            return latex_escape(text).replace("\x00", r"\textbf{").replace("\x01", "}")

        numeric = self._numeric()
        out = [r"\begin{table}[h]", r"\centering",
               r"\begin{tabular}{" + "".join("r" if n else "l" for n in numeric) + "}", r"\toprule",
               " & ".join(c.latex_header for c in self.columns) + r" \\", r"\midrule"]
        body_n = len(self.rows) - self.footer_rows
        for k, row in enumerate(raw):
            if k == body_n and self.footer_rows:
                out.append(r"\midrule")
            out.append(" & ".join(tex(t) for t in row) + r" \\")
        out += [r"\bottomrule", r"\end{tabular}"]
        extra = [latex_escape(n) for n in self.notes]
        if len(self._reasons) == 1:
            extra.append(f"n/a: {latex_escape(self._reasons[0])}")
        else:
            extra += [f"n/a$^{{{k + 1}}}$: {latex_escape(r)}" for k, r in enumerate(self._reasons)]
        if extra:
            out.append(r"\par\smallskip{\footnotesize " + r" \\ ".join(extra) + "}")
        out.append(r"\caption{" + latex_escape(self.title) + "}")
        if self.label:
            out.append(r"\label{" + self.label + "}")
        out.append(r"\end{table}")
        return "\n".join(out) + "\n"

    def to_csv(self) -> str:
        """Header of column names, one line per row; floats at full precision (``repr``), n/a as ``n/a``."""
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow([c.name for c in self.columns])
        for row in self.rows:
            cells = []
            for c in self.columns:
                value = row.get(c.name)
                if _is_numeric(value) and not isinstance(value, numbers.Integral):
                    cells.append(repr(float(value)) if math.isfinite(float(value)) else format_cell(value))
                else:
                    cells.append(format_cell(value))
            writer.writerow(cells)
        return buf.getvalue()

    def to_json(self) -> str:
        """Everything, losslessly: non-finite floats as ``{"float": "inf"}``, n/a as
        ``{"not_available": reason}``, missing cells as ``null``.
        """
        data = {
            "title": self.title,
            "columns": [{"name": c.name, "direction": c.direction, "decimals": c.decimals, "latex": c.latex}
                        for c in self.columns],
            "rows": [{c.name: _json_cell(r.get(c.name)) for c in self.columns} for r in self.rows],
            "footer_rows": self.footer_rows,
            "notes": list(self.notes),
            "bold_best": self.bold_best,
            "label": self.label,
        }
        return json.dumps(data, indent=2, ensure_ascii=False, allow_nan=False) + "\n"

    @classmethod
    def from_json(cls, text: str) -> Table:
        """The table ``to_json`` wrote."""
        data = json.loads(text)
        columns = tuple(Column(**c) for c in data["columns"])
        rows = tuple({k: _from_json_cell(v) for k, v in r.items() if v is not None} for r in data["rows"])
        return cls(data["title"], columns, rows, tuple(data["notes"]), data["footer_rows"], data["bold_best"],
                   data["label"])

    def write_all(self, directory: str | os.PathLike, stem: str) -> dict[str, Path]:
        """Write ``stem.{md,tex,csv,json}`` into ``directory`` (created if needed), each atomically;
        returns the paths by suffix.
        """
        from nsim.io import atomic_path

        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        out = {}
        for suffix, text in (("md", self.to_markdown()), ("tex", self.to_latex()), ("csv", self.to_csv()),
                             ("json", self.to_json())):
            path = directory / f"{stem}.{suffix}"
            with atomic_path(path) as tmp:
                tmp.write_text(text, encoding="utf-8")
            out[suffix] = path
        return out


def _superscript_markers(text: str) -> str:
    """``n/a12`` markers as ``n/a¹²`` (only right after ``n/a``)."""
    if not text.startswith(NA) or text == NA:
        return text
    rest = text[len(NA):]
    digits = len(rest) - len(rest.lstrip("0123456789"))
    return NA + rest[:digits].translate(_SUPERSCRIPTS) + rest[digits:]
