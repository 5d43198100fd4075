"""Every output context escaped: a run path or a plug-in's name is the user's text, and
lands in CSV cells (which a spreadsheet would evaluate), markdown reports (where it could become a
live remote image, raw HTML or a shifted table) and HTML pages. Each reaches its reader as text."""
import csv
import io
import re
import shutil

import pytest
from hypothesis import given, settings, strategies as st

from conftest import dc
from deepcontact.escape import CsvWriter, csv_cell, md_text
from deepcontact.html import _cells, _inline

pytestmark = pytest.mark.audit

FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "|")
HOSTILE_RUNS = ['=HYPERLINK("http:evil","x")', "+cmd|' -C calc'!A0", "@SUM(1+1)", "-1+1",
                "![p](http:__evil_i.png)<img src=x onerror=alert(1)>|col"]


def is_number(text):
    try:
        float(text)
        return True
    except ValueError:
        return False


@given(st.text(min_size=1, max_size=30))
@settings(max_examples=400, deadline=None)
def test_no_csv_cell_a_spreadsheet_would_evaluate(text):
    buf = io.StringIO()
    CsvWriter(buf).writerow([text, 1.5, -2])
    cell, number, negative = next(csv.reader(io.StringIO(buf.getvalue(), newline="")))
    assert not cell.startswith(FORMULA_START) or is_number(cell)
    assert cell in (text, "'" + text) and number == "1.5" and negative == "-2"


@given(st.text(max_size=40))
@settings(max_examples=400, deadline=None)
def test_markdown_text_reads_back_as_itself_and_stays_in_its_cell(text):
    escaped = md_text(text)
    assert "\n" not in escaped
    assert _cells(f"| {escaped} | next |") == [escaped.strip(), "next"] or not escaped.strip()
    shown = _inline(escaped)   # what the HTML page shows: the text itself, escaped for HTML
    assert "<img" not in shown and "<script" not in shown
    plain = re.sub(r"[\r\n\u2028\u2029]+", " ", text).replace("\x00", "")
    assert shown == _inline(md_text(plain))


def test_hostile_run_paths_are_text_in_every_report(run, tmp_path, monkeypatch):
    for name in HOSTILE_RUNS:
        shutil.copytree(run, tmp_path / name)
    monkeypatch.chdir(tmp_path)   # (given as typed: the cell starts with the name)
    r = dc("evaluate", "--starts", "zero,builtin", "--every", "60", "--no-budgets", "-q",
           "-o", tmp_path / "report", "--", *HOSTILE_RUNS)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "report"
    for name in ("steps.csv", "summary.csv"):
        for row in csv.reader(io.StringIO((out / name).read_text(), newline="")):
            for cell in row:
                assert not cell.startswith(FORMULA_START) or is_number(cell), (name, cell)
    assert any(row[0].startswith("'") for row in csv.reader(io.StringIO((out / "steps.csv").read_text())))
    md = (out / "report.md").read_text()
    assert not re.search(r"(?<!\\)!\\?\[p", md) and not re.search(r"(?<!\\)<img", md) and "\\<img" in md
    table = [line for line in md.splitlines() if line.startswith("|")]
    widths = {len(_cells(line)) for line in table[:2 + 2]}   # the summary table: header, rule, rows
    assert len(widths) == 1, table[:4]
    page = (out / "report.html").read_text()
    assert "onerror=alert" not in page.replace("onerror=alert(1)&gt;", "") and "<img src=x" not in page
