"""Tables: Markdown and fixed-width rendering, n/a for missing values with their reasons."""

from __future__ import annotations

import math

import pytest

from nsim.metrics.results_table import NotAvailable, format_cell, to_markdown, to_text

ROWS = [
    {"method": "ours", "PSNR": 31.23456, "LPIPS": NotAvailable("no LPIPS weights; run fetch"), "frames": 12},
    {"method": "baseline", "PSNR": math.inf, "LPIPS": 0.1, "frames": 3},
]


def test_format_cell():
    assert format_cell(None) == "n/a"
    assert format_cell(NotAvailable("x")) == "n/a"
    assert format_cell(0.123456, 3) == "0.123"
    assert format_cell(7) == "7" and format_cell(True) == "yes"
    assert format_cell(math.nan) == "nan" and format_cell(-math.inf) == "-inf"


def test_markdown():
    text = to_markdown(ROWS, decimals={"PSNR": 2})
    assert text.splitlines() == [
        "| method | PSNR | LPIPS | frames |",
        "|:---|---:|---:|---:|",
        "| ours | 31.23 | n/a | 12 |",
        "| baseline | inf | 0.1000 | 3 |",
        "",
        "- n/a: no LPIPS weights; run fetch",
    ]


def test_text_is_fixed_width():
    rows = [{k: row[k] for k in ("method", "PSNR", "LPIPS")} for row in ROWS]
    text = to_text(rows, decimals=2)
    lines = text.splitlines()
    assert lines[:4] == [
        "method     PSNR  LPIPS",
        "--------  -----  -----",
        "ours      31.23    n/a",
        "baseline    inf   0.10",
    ]
    assert lines[4] == "n/a: no LPIPS weights; run fetch"


def test_missing_cells_and_typos():
    assert "| a | n/a |" in to_markdown([{"name": "a"}], columns=["name", "value"])
    with pytest.raises(ValueError, match="not in"):
        to_text([{"name": "a", "vaule": 1.0}], columns=["name", "value"])
    with pytest.raises(ValueError, match="unknown column"):
        to_text(ROWS, decimals={"PNSR": 2})
