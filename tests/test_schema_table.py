"""One verdict for a step file: the schema's table (step/strict.py, native step_strict.hpp) is final
where it accepts a file (no XSD runs on it), so it must refuse whatever libxml2's validator of
step.xsd refuses. Held to it on the schema's own edge cases, generated from the XSD
(schema_corpus.py), and on the disagreements an audit found."""
import re
from collections import Counter

import pytest
from lxml import etree

from conftest import dc
from deepcontact import _box2d, schema
from deepcontact.errors import InputError
from deepcontact.step.reader import read_step, step_schema, strict_table
from schema_corpus import corpus

XSI = 'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'


def xsd_verdicts(path, text):
    """(the native validator's verdict, lxml's): whether each, with its own libxml2, finds the
    file valid against step.xsd (a root other than <step> is not a step file)."""
    root, _, _, errors = _box2d.validate_step_file(str(path), step_schema(), 1)
    parser = etree.XMLParser(strip_cdata=False, resolve_entities=False, no_network=True, load_dtd=False)
    try:
        lxml_valid = schema.schema("step").validate(etree.fromstring(text.encode(), parser))
    except etree.XMLSyntaxError:
        lxml_valid = False
    return root == "step" and not errors, lxml_valid


def test_the_table_agrees_with_the_xsd_on_the_schemas_own_edge_cases(tmp_path):
    """Every case of the generated corpus judged by the table alone (check_step_table), by the
    native validator and by lxml's: where the table decides, it agrees with both; where libxml2's
    versions disagree it must leave the file to the XSD (it cannot agree with both)."""
    path, counts, wrong = tmp_path / "step.xml", Counter(), []
    for label, text in corpus():
        path.write_text(text)
        native, lxml_valid = xsd_verdicts(path, text)
        verdict, problem = _box2d.check_step_table(str(path), strict_table())
        counts[verdict] += 1
        if verdict == "xsd":
            continue
        if native != lxml_valid or (verdict == "valid") != native:
            wrong.append(f"{label}: table {verdict} ({problem or 'no problem'}), XSD native "
                         f"{'valid' if native else 'invalid'}, lxml {'valid' if lxml_valid else 'invalid'}")
    assert not wrong, f"{len(wrong)} disagreements:\n" + "\n".join(wrong[:40])
    # (the corpus reaches every verdict, and the table decides nearly all of it)
    assert counts["valid"] > 500 and counts["invalid"] > 1200 and counts["xsd"] < 0.1 * sum(counts.values()), counts


def test_the_table_decides_every_file_dc_writes(pile_run):
    """Deferring costs an XSD pass: no file dc writes is left to the XSD."""
    for path in sorted(pile_run.glob("seed-*/step-*.xml"))[::5]:
        assert _box2d.check_step_table(str(path), strict_table()) == ("valid", ""), path


def _edited(pile_run, tmp_path, old, new):
    """A step file of pile_run with contacts, the first match of the pattern `old` replaced."""
    text = max(pile_run.glob("seed-*/step-*.xml"), key=lambda p: p.stat().st_size).read_text()
    edited, n = re.subn(old, new, text, count=1)
    assert n == 1, old
    path = tmp_path / "step-000000.xml"
    path.write_text(edited)
    return path


# What the audit found the table accepting and the XSD refusing (dc validate passed such files and
# dc rasterize built datasets from them): text in an element of empty content, as white space,
# CDATA or a character reference; attributes of the XML Schema instance's namespace; a signed
# zero in an unsigned field.
REFUSED = {
    "white space in an empty element": (r'<spin omega="([^"]*)"/>', r'<spin omega="\1"> </spin>'),
    "a newline in an empty element": (r'<spin omega="([^"]*)"/>', '<spin omega="\\1">\n</spin>'),
    "CDATA white space in an empty element": (r'<spin omega="([^"]*)"/>', r'<spin omega="\1"><![CDATA[ ]]></spin>'),
    "an empty CDATA section in an empty element": (r'<gravity ([^/]*)/>', r'<gravity \1><![CDATA[]]></gravity>'),
    "a character reference to a space in an empty element": (r'<impulse ([^/]*)/>', r'<impulse \1>&#32;</impulse>'),
    "a character reference to a newline in an empty element": (r'<impulse ([^/]*)/>', r'<impulse \1>&#10;</impulse>'),
    "xsi:nil": (r'<step ', f'<step {XSI} xsi:nil="true" '),
    "xsi:nil false": (r'<gravity ', f'<gravity {XSI} xsi:nil="false" '),
    "an unknown xsi attribute": (r'<solver ', f'<solver {XSI} xsi:foo="1" '),
    "xsi:type of another type": (r'<position ', f'<position {XSI} xsi:type="scalar" '),
    "-0 in an unsigned field": (r' id="\d+"', ' id="-0"'),
    "+0 in an unsigned field": (r' id="\d+"', ' id="+0"'),
}


@pytest.mark.parametrize("case", REFUSED)
def test_what_the_xsd_refuses_dc_refuses(pile_run, tmp_path, case):
    """Each by the XSD, by the reader that dc validate, evaluate and export read through, and by
    dc validate itself (one line naming the file, exit 1)."""
    path = _edited(pile_run, tmp_path, *REFUSED[case])
    assert _box2d.validate_step_file(str(path), step_schema(), 1)[3]
    with pytest.raises(InputError):
        read_step(path, validate=True)
    r = dc("validate", str(path))
    assert r.returncode == 1 and r.stdout.startswith(f"{path}:"), (r.stdout, r.stderr)
    assert _box2d.check_step_table(str(path), strict_table())[0] != "valid"


# Forms the table leaves to the XSD (libxml2 2.9 and later versions differ on them, or the table
# does not read them): the XSD's verdict is dc's, whichever it is.
DEFERRED = {
    "white space around an int": (r' seed="(\d+)"', r' seed=" \1 "'),
    "a plus sign on an unsigned int": (r' id="(\d+)"', r' id="+\1"'),
    "an exponent without digits": (r'<gravity x="0"', '<gravity x="0e"'),
    "a CDATA section of white space in element content": (r'<shape>', '<shape><![CDATA[ ]]>'),
    "xsi:type of its own type": (r'<gravity ', f'<gravity {XSI} xsi:type="vector" '),
}


@pytest.mark.parametrize("case", DEFERRED)
def test_what_the_table_does_not_decide_the_xsd_does(pile_run, tmp_path, case):
    """The XSD judges the file: the reader accepts it only where the XSD does (its own checks may
    still refuse it: "0e" is no number numpy reads), and says what is wrong in the XSD's words."""
    path = _edited(pile_run, tmp_path, *DEFERRED[case])
    assert _box2d.check_step_table(str(path), strict_table())[0] == "xsd"
    xsd_valid = not _box2d.validate_step_file(str(path), step_schema(), 1)[3]
    try:
        read_step(path, validate=True)
        assert xsd_valid
    except InputError as e:
        assert "left to the XSD" not in e.message


@pytest.mark.parametrize("case", ["white space in an empty element", "xsi:nil false"])
def test_every_command_that_reads_a_run_refuses_what_the_xsd_refuses(pile_run, tmp_path, case):
    """dc validate refused such a file, but dc rasterize built a dataset from it, dc render drew
    it and dc evaluate judged it: they read with the schema's table off."""
    import shutil
    run = tmp_path / "run"
    shutil.copytree(pile_run, run)
    path = max(run.glob("seed-000000/step-*.xml"), key=lambda p: p.stat().st_size)
    edited, n = re.subn(REFUSED[case][0], REFUSED[case][1], path.read_text(), count=1)
    assert n == 1
    path.write_text(edited)
    step = int(path.stem.split("-")[1])
    for args in (["rasterize", run, "-o", tmp_path / "data"], ["render", path, "-o", tmp_path / "s.png"],
                 ["evaluate", run, "--starts", "builtin", "--every", str(step), "--no-budgets", "--no-plots",
                  "-o", tmp_path / "e"]):
        r = dc(*args)
        assert r.returncode == 1 and str(path) in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
        assert not (tmp_path / "data").exists() and not (tmp_path / "s.png").exists() and not (tmp_path / "e").exists()
