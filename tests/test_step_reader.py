"""The native streaming step reader against the lxml reference, value for value, on every kind of
step file, plain and compressed, and on hostile input (one error naming the file and line)."""
import gzip
import os
import re
import shutil

import numpy as np
import pytest

from deepcontact.errors import InputError
from deepcontact.step import reader, reader_lxml

from conftest import dc, simulate, written

SCENES = "datasets/scenes"

# Every kind of step file the writer makes: circles on walls, polygons with the block solver,
# edges with restitution and damping, sleeping, continuous collision, and the project's solver
# with its <solve> header line.
KINDS = {
    "pile": ("pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps", "150"),
    "boxes-and-circles": (f"{SCENES}/boxes-and-circles.xml", "--steps", "120"),
    "bouncing": (f"{SCENES}/bouncing.xml", "--steps", "150"),
    "sleeping": (f"{SCENES}/sleeping.xml", "--steps", "200"),
    "bullet": ("bullet", "--steps", "60"),
    "pyramid": ("pyramid", "--param", "base=6", "--steps", "40"),
    "pgs": ("pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5", "--steps", "80",
            "--solver", "pgs", "--tolerance", "1e-4", "--max-iterations", "200"),
}


@pytest.fixture(scope="module", params=sorted(KINDS))
def kind_run(request, tmp_path_factory):
    return request.param, written(tmp_path_factory.mktemp(request.param) / "run", "simulate", *KINDS[request.param])


def assert_same(a, b):
    ha, ba, ca = a
    hb, bb, cb = b
    assert ha.keys() == hb.keys()
    for key in ha:
        if isinstance(ha[key], np.ndarray):
            assert ha[key].dtype == hb[key].dtype and np.array_equal(ha[key], hb[key]), key
        else:
            assert type(ha[key]) is type(hb[key]) and ha[key] == hb[key], key
    for x, y in ((ba, bb), (ca, cb)):
        assert x.keys() == y.keys()
        for key in x:
            assert x[key].dtype == y[key].dtype and x[key].shape == y[key].shape, key
            assert np.array_equal(x[key], y[key]), key   # bit for bit: no NaN can be in a step file


def test_the_native_reader_matches_the_lxml_reference(kind_run):
    name, run = kind_run
    files = sorted(run.glob("seed-*/step-*.xml"))
    assert files
    contacts = 0
    for path in files[:: max(1, len(files) // 12)] + files[-1:]:
        native = reader.read_step(path)
        assert_same(native, reader_lxml.read_step(path))
        assert_same(reader.read_step_for_grid(path), reader_lxml.read_step_for_grid(path))
        contacts += len(native[2]["manifold"])
    assert contacts > 0, name
    solve = reader.read_step(files[-1])[0]["solve"]
    if name == "pgs":   # how the project's solver stepped it, for the viewer and reports
        assert "<solve " in files[-1].read_text() and int(solve["iterations"]) >= 0 and float(solve["residual"]) >= 0
    else:
        assert solve is None


def test_a_compressed_step_reads_as_the_plain_one(pile_run, tmp_path):
    src = sorted(pile_run.glob("seed-*/step-*.xml"))[-1]
    packed = tmp_path / (src.name + ".gz")
    packed.write_bytes(gzip.compress(src.read_bytes(), 1, mtime=0))
    assert_same(reader.read_step(packed), reader.read_step(src))
    assert_same(reader_lxml.read_step(packed), reader.read_step(src))


# hostile input ---------------------------------------------------------------------------------

def mutated(src, tmp_path, pattern, replacement, count=1):
    text, n = re.subn(pattern, replacement, src.read_text(), count=count)
    assert n >= 1, pattern
    path = tmp_path / src.name
    path.write_text(text)
    return path, text


@pytest.mark.parametrize("pattern,replacement,needle", [
    (r'(<impulse n=")[^"]+', r"\1nan", "not finite"),
    (r'(<velocity x=")[^"]+', r"\1abc", "is not a number"),
    (r'<spin omega="[^"]+"/>', "", "has no <spin omega"),
    (r'(<bodies count=")\d+', r"\g<1>999", 'but it holds'),
    (r'(<contact [^>]*\bmaster=")\d+', r"\g<1>99999999999", "out of range"),
    (r'(<contact [^>]*\bpoint=")\d+', r"\g<1>-1", "out of range"),
    (r'(<body [^>]*\btype=")\w+', r"\1liquid", "unknown value"),
    (r'(<manifold type=")\w+', r"\1spline", "unknown value"),
    (r'(<step [^>]*\bseed=")\d+', r"\1x", "whole number"),
    (r'(<fixtures master=")\d+', r"\g<1>77777", "which no body has"),
    (r"<header>", "<header><header>", "not a well-formed"),
])
def test_bad_values_name_the_file_and_line(pile_run, tmp_path, pattern, replacement, needle):
    src = sorted(pile_run.glob("seed-*/step-*.xml"))[-1]
    path, text = mutated(src, tmp_path, pattern, replacement)
    with pytest.raises(InputError) as native:
        reader.read_step(path, validate=False)
    assert needle in native.value.message and native.value.path == str(path)
    if needle != "which no body has":   # a contact's fixture: the whole file is the context
        assert native.value.line, native.value
        # the line the reader names is the element that is wrong (or, for a count, the holder)
        assert native.value.line <= text.count("\n") + 1
    with pytest.raises(InputError):   # the reference refuses it too
        reader_lxml.read_step(path, validate=False)
    with pytest.raises(InputError) as checked:   # and the schema, checked in the same pass
        reader.read_step(path, validate=True)
    assert checked.value.path == str(path)


def test_the_line_named_is_the_line_of_the_bad_value(pile_run, tmp_path):
    src = sorted(pile_run.glob("seed-*/step-*.xml"))[-1]
    lines = src.read_text().splitlines(keepends=True)
    k = [i for i, line in enumerate(lines) if "<impulse " in line][3]
    lines[k] = re.sub(r'n="[^"]+"', 'n="inf"', lines[k])
    path = tmp_path / src.name
    path.write_text("".join(lines))
    with pytest.raises(InputError) as e:
        reader.read_step(path, validate=False)
    assert e.value.line == k + 1 and "contact 3" in e.value.message


def test_files_that_are_not_step_files(pile_run, tmp_path):
    src = sorted(pile_run.glob("seed-*/step-*.xml"))[-1]
    cases = {
        "doctype.xml": src.read_text().replace("?>\n", '?>\n<!DOCTYPE step [<!ENTITY x SYSTEM "file:///etc/passwd">]>\n', 1),
        "scene.xml": (pile_run / "seed-000000" / "scene.xml").read_text(),
        "empty.xml": "",
        "cut.xml": src.read_text()[:4000],
    }
    needles = {"doctype.xml": "DOCTYPE", "scene.xml": "root element is <scene>", "empty.xml": "",
               "cut.xml": "not a well-formed"}
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError) as e:
            reader.read_step(tmp_path / name, validate=False)
        assert needles[name] in e.value.message and e.value.path == str(tmp_path / name), (name, e.value)
    cut = tmp_path / "cut.xml.gz"
    cut.write_bytes(gzip.compress(src.read_bytes(), 1, mtime=0)[:3000])
    with pytest.raises(InputError) as e:
        reader.read_step(cut, validate=False)
    assert "cannot read" in e.value.message or "not a well-formed" in e.value.message, e.value
    with pytest.raises(InputError) as e:
        reader.read_step(tmp_path / "missing.xml")
    assert "cannot read" in e.value.message
    fifo = tmp_path / "fifo.xml"
    os.mkfifo(fifo)
    with pytest.raises(InputError) as e:   # refused at once: reading it would wait for a writer
        reader.read_step(fifo)
    assert "not a regular file" in e.value.message


def test_a_huge_attribute_is_refused_in_one_short_line(pile_run, tmp_path):
    src = sorted(pile_run.glob("seed-*/step-*.xml"))[-1]
    path = tmp_path / src.name
    path.write_text(src.read_text().replace("<step ", '<step junk="' + "x" * 20_000_000 + '" ', 1))
    with pytest.raises(InputError) as e:
        reader.read_step(path, validate=False)
    assert len(str(e.value)) < 600
