"""Table: arrows in headers, bold best values, n/a footnotes, LaTeX/CSV/JSON output and write_all."""

from __future__ import annotations

import csv
import io
import json
import math

import pytest

from nsim.metrics.results_table import Column, NotAvailable, Table, latex_escape

COLUMNS = (Column("camera"), Column("PSNR", "higher", 2), Column("AbsRel", "lower", 3), Column("frames"))


def table(**kw) -> Table:
    rows = (
        {"camera": "left_fisheye", "PSNR": 23.104, "AbsRel": 0.25, "frames": 10},
        {"camera": "back", "PSNR": 21.8, "AbsRel": 0.2449, "frames": 12},
        {"camera": "front", "PSNR": 23.1, "AbsRel": NotAvailable("no depth"), "frames": 3},
    )
    return Table("Spot cameras", COLUMNS, rows, **kw)


def test_markdown_arrows_bold_and_single_reason():
    text = table(notes=("depth metrics without median scaling",), bold_best=True).to_markdown()
    assert text.splitlines() == [
        "### Spot cameras",
        "",
        "| camera | PSNR ↑ | AbsRel ↓ | frames |",
        "|:---|---:|---:|---:|",
        "| left_fisheye | **23.10** | 0.250 | 10 |",  # 23.104 and 23.1 tie at 2 decimals: both bold
        "| back | 21.80 | **0.245** | 12 |",
        "| front | **23.10** | n/a | 3 |",
        "",
        "- depth metrics without median scaling",
        "- n/a: no depth",
    ]
    assert "**" not in table().to_markdown()  # bold is opt-in


def test_two_reasons_get_markers_and_footer_rows_are_ruled_off():
    rows = (
        {"camera": "a", "PSNR": NotAvailable("no weights"), "AbsRel": 0.1},
        {"camera": "b", "PSNR": 30.0, "AbsRel": NotAvailable("no depth camera")},
        {"camera": "median", "PSNR": 99.0, "AbsRel": 0.01},  # a footer row: never bold
    )
    t = Table("T", COLUMNS[:3], rows, footer_rows=1, bold_best=True)
    md = t.to_markdown().splitlines()
    assert md[4:7] == ["| a | n/a¹ | **0.100** |", "| b | **30.00** | n/a² |", "| *median* | 99.00 | 0.010 |"]
    assert md[-2:] == ["- n/a¹: no weights", "- n/a²: no depth camera"]
    text = t.to_text().splitlines()
    assert text[0] == "T" and text[1].split() == ["camera", "PSNR", "↑", "AbsRel", "↓"]
    assert text[5] == text[2] and text[6].startswith("median")  # a rule before the footer
    tex = t.to_latex()
    assert r"a & n/a$^{1}$ & \textbf{0.100} \\" in tex
    assert r"n/a$^{1}$: no weights \\ n/a$^{2}$: no depth camera" in tex
    body = tex.split(r"\midrule")
    assert len(body) == 3 and body[2].lstrip().startswith(r"median & 99.00 & 0.010 \\")


def test_latex_booktabs():
    tex = table(label="tab:spot", notes=("5% of pixels",), bold_best=True).to_latex()
    lines = tex.splitlines()
    assert lines[:6] == [r"\begin{table}[h]", r"\centering", r"\begin{tabular}{lrrr}", r"\toprule",
                         r"camera & PSNR $\uparrow$ & AbsRel $\downarrow$ & frames \\", r"\midrule"]
    assert r"left\_fisheye & \textbf{23.10} & 0.250 & 10 \\" in lines
    assert r"front & \textbf{23.10} & n/a & 3 \\" in lines
    assert lines[-6:] == [r"\bottomrule", r"\end{tabular}",
                          r"\par\smallskip{\footnotesize 5\% of pixels \\ n/a: no depth}",
                          r"\caption{Spot cameras}", r"\label{tab:spot}", r"\end{table}"]


def test_latex_escape_and_custom_headers():
    assert latex_escape("δ<1.25²") == r"$\delta<$1.25$^2$"
    assert latex_escape("a_b & 50% #1 {x}") == r"a\_b \& 50\% \#1 \{x\}"
    assert latex_escape("Δ sim−real [m]") == r"$\Delta$ sim$-$real [m]"
    col = Column("δ<1.25", "higher", 3, latex=r"$\delta_{1.25}$")
    assert col.header == "δ<1.25 ↑" and col.latex_header == r"$\delta_{1.25}$ $\uparrow$"


def test_csv_full_precision_and_na():
    rows = list(csv.reader(io.StringIO(table().to_csv())))
    assert rows[0] == ["camera", "PSNR", "AbsRel", "frames"]
    assert rows[1] == ["left_fisheye", "23.104", "0.25", "10"]
    assert rows[3] == ["front", "23.1", "n/a", "3"]
    assert float(rows[2][2]) == 0.2449


def test_json_round_trip():
    rows = ({"camera": "x", "PSNR": math.inf, "AbsRel": NotAvailable("r")}, {"camera": "y", "PSNR": 1.0 / 3.0})
    t = Table("J", COLUMNS, rows, notes=("n",), footer_rows=1, bold_best=True, label="tab:j")
    data = json.loads(t.to_json())
    assert data["columns"][1] == {"name": "PSNR", "direction": "higher", "decimals": 2, "latex": None}
    assert data["rows"][0] == {"camera": "x", "PSNR": {"float": "inf"}, "AbsRel": {"not_available": "r"},
                               "frames": None}
    back = Table.from_json(t.to_json())
    assert back == t and back.rows[1]["PSNR"] == 1.0 / 3.0
    nan = Table("N", (Column("v", "lower"),), ({"v": math.nan},))
    assert math.isnan(Table.from_json(nan.to_json()).rows[0]["v"])


def test_write_all(tmp_path):
    paths = table().write_all(tmp_path / "tables", "spot-rgb")
    assert sorted(paths) == ["csv", "json", "md", "tex"]
    for suffix, path in paths.items():
        assert path == tmp_path / "tables" / f"spot-rgb.{suffix}" and path.read_text(encoding="utf-8")
    assert sorted(p.name for p in (tmp_path / "tables").iterdir()) == [
        "spot-rgb.csv", "spot-rgb.json", "spot-rgb.md", "spot-rgb.tex"]  # no temporary files left
    assert Table.from_json(paths["json"].read_text(encoding="utf-8")) == table()


def test_bad_tables():
    with pytest.raises(ValueError, match="not in"):
        Table("t", COLUMNS, ({"camera": "a", "PNSR": 1.0},))
    with pytest.raises(ValueError, match="duplicate column"):
        Table("t", (Column("a"), Column("a")), ())
    with pytest.raises(ValueError, match="direction"):
        Column("PSNR", "up")
    with pytest.raises(ValueError, match="footer_rows"):
        Table("t", COLUMNS, ({"camera": "a"},), footer_rows=2)
    with pytest.raises(TypeError, match="expected a number"):
        Table("t", COLUMNS, ({"camera": ["a"]},))
    assert Table("t", ("a", "b"), ({"a": 1},)).columns == (Column("a"), Column("b"))
