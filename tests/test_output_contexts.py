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
from deepcontact.escape import CsvWriter, md_text
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


# --- No link or image is ever live from data: a checker for every markdown report ---------------

MARKER = "tracker.invalid"
HOSTILE_TEXT = [f"x`![t](https://{MARKER}/p.png)`y", f"<img src=x onerror=alert(1)>{MARKER}",
                f"[l](http://{MARKER}) www.{MARKER} https://{MARKER}/a &amp; <https://{MARKER}>"]
_LIVE = {"image or link": re.compile(r"!?\[[^\]]*\]\(([^)]*)\)"), "raw HTML or autolink": re.compile(r"<[A-Za-z/!?]"),
         "entity": re.compile(r"&(#\d+|#x[0-9a-f]+|[a-z][a-z0-9]*);", re.I),
         "bare address": re.compile(r"[a-z][a-z0-9+.-]*://|www\.", re.I)}


def live_markup(md, pictures=()):
    """What in markdown text a renderer (CommonMark, GitHub's) would make live: an image or link
    to anything but the pictures the command drew, raw HTML, an entity, a bare address; and a
    code span holding the marker (its backticks came from data). Backslash-escaped characters are
    text, and are taken out first."""
    text = re.sub(r"\\[!-/:-@\[-`{-~]", "\x00", md)
    found = []
    for what, pattern in _LIVE.items():
        for m in pattern.finditer(text):
            if what == "image or link" and m.group(1) in pictures:
                continue
            found.append(f"{what}: {m.group()!r}")
    found += [f"code span: {s!r}" for s in re.findall(r"`[^`]*`", text) if "invalid" in s]
    return found


@given(st.text(max_size=60) | st.sampled_from(HOSTILE_TEXT))
@settings(max_examples=400, deadline=None)
def test_no_text_through_md_text_or_the_protocol_line_is_live(text):
    from deepcontact.protocol import protocol, protocol_line
    assert not live_markup(md_text(text)), md_text(text)
    line = protocol_line({**protocol(), "command": f"dc evaluate {text}", "cpu": text})
    assert not live_markup(line), line


def test_the_live_markup_checker_finds_what_it_must():
    for bad in (f"![t](https://{MARKER}/p.png)", "<img src=x>", f"see https://{MARKER}", f"www.{MARKER}",
                "&lt;", f"a `{MARKER}` b", "[l](x.png)"):
        assert live_markup(bad), bad
    assert not live_markup("![convergence](convergence.png) `@w` a < b", pictures={"convergence.png"})


@pytest.fixture(scope="module")
def hostile_run(tmp_path_factory):
    """A small pile run whose scene name is hostile text, lying under a hostile run path (a path
    may hold '/': the address is folders)."""
    tmp = tmp_path_factory.mktemp("hostile-md")
    scene = tmp / "scene.xml"
    assert dc("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5",
              "--write-scene", scene).returncode == 0
    from xml.sax.saxutils import quoteattr
    text = scene.read_text()
    scene.write_text(text.replace('name="pile"', f"name={quoteattr(' '.join(HOSTILE_TEXT))}", 1))
    run = tmp / HOSTILE_TEXT[0] / "run"
    run.parent.mkdir(parents=True)
    assert dc("simulate", scene, "--steps", "100", "-q", "-o", run).returncode == 0
    return run


@pytest.mark.parametrize("mode", ["replay", "closed-loop"])
def test_no_report_holds_live_markup_from_a_run_or_an_output_path(hostile_run, tmp_path, mode, monkeypatch):
    from deepcontact import protocol
    out = tmp_path / HOSTILE_TEXT[1].replace("/", "") / "report"
    args = ["evaluate", hostile_run, "--starts", "zero,builtin", "-q", "-o", out]
    args += ["--closed-loop", "--steps", "30"] if mode == "closed-loop" else ["--every", "20", "--no-budgets"]
    # the command line as the dc entry point records it: the paths as typed, in every report
    monkeypatch.setattr(protocol, "command_line", " ".join(["dc", *map(str, args)]))
    r = dc(*args)
    assert r.returncode == 0, r.stderr
    md = (out / "report.md").read_text()
    assert MARKER in md and not live_markup(md, {p.name for p in out.glob("*.png")}), live_markup(md)
    page = (out / "report.html").read_text()
    assert not re.search(r"<a\b|href=(?!\"#)|<img(?![^>]*src=\"data:)", page)   # (text: &lt;img)
