"""Step files: schema-valid (lxml and xmllint), exact float round trip, nothing non-finite."""
import shutil
import subprocess

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from deepcontact import _box2d, schema
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.simulate.engines import Box2D
from deepcontact.step.reader import read_step
from deepcontact.step.writer import step_writer


def step_files(run_dir):
    return sorted(run_dir.glob("seed-*/step-*.xml"))


def test_every_file_is_schema_valid(pile_run):
    files = step_files(pile_run) + sorted(pile_run.glob("seed-*/scene.xml"))
    assert len(files) == 151
    for path in files:
        kind, _, errors = schema.validate(path)
        assert errors == [], errors[:3]


@pytest.mark.skipif(shutil.which("xmllint") is None, reason="xmllint (libxml2-utils) not installed")
def test_an_independent_validator_agrees(pile_run):
    steps = step_files(pile_run)[::10]
    out = subprocess.run(["xmllint", "--noout", "--schema", schema.schema_path("step"), *map(str, steps)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    scene = pile_run / "seed-000000" / "scene.xml"
    out = subprocess.run(["xmllint", "--noout", "--schema", schema.schema_path("scene"), str(scene)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_written_arrays_read_back_bit_for_bit():
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    world = build_world(scene)
    writer = step_writer(scene, 0, Box2D())
    checked = 0
    for k in range(150):
        bodies, contacts = world.step(scene.dt, 8, 3, record=True)
        if k % 25 and k != 149:
            continue
        xml = writer.render(k, k * 0.01, world.last_dt_ratio, bodies, contacts)
        path = f"/tmp/dc-roundtrip-{k}.xml"
        open(path, "wb").write(xml)
        header, b, c = read_step(path)
        assert header["index"] == k and header["scene"] == "pile"
        for key in b:
            assert np.array_equal(b[key], bodies[key]), key
        for key in c:
            assert np.array_equal(c[key], contacts[key]), key
        checked += len(c["manifold"])
    assert checked > 50


finite32 = st.floats(width=32, allow_nan=False, allow_infinity=False)


def _shortest(text, values):
    """Each text no longer than Python's shortest repr of its float64 value (plus an exponent's
    sign and padding): the shortest round-tripping text, not merely a round-tripping one."""
    return all(len(t.replace("e+", "e").replace("e-0", "e-")) <= len(repr(float(v))) + 4 for t, v in zip(text, values))


def test_float32_text_round_trips_exactly_over_random_bit_patterns():
    """200,000 random float32 bit patterns (every exponent, subnormals and -0.0 among them) and the
    extremes: text and back gives the same bits."""
    bits = np.random.default_rng(0).integers(0, 2 ** 32, size=200_000, dtype=np.uint64).astype(np.uint32)
    extremes = [0.0, -0.0, np.finfo(np.float32).max, -np.finfo(np.float32).max, np.finfo(np.float32).tiny,
                np.finfo(np.float32).smallest_subnormal, 1.0, 0.1, 16777217.0]
    a = np.concatenate([bits.view(np.float32), np.array(extremes, np.float32)])
    a = a[np.isfinite(a)]
    text = _box2d.format_floats(a)
    back = np.array(text, dtype=np.float32)
    assert np.array_equal(a.view(np.uint32), back.view(np.uint32))
    assert _shortest(text, a)


@settings(max_examples=200, deadline=None)
@given(st.lists(finite32, min_size=1, max_size=20))
def test_float32_text_round_trips_exactly(values):
    a = np.array(values, dtype=np.float32)
    text = _box2d.format_floats(a)
    back = np.array([np.float32(t) for t in text], dtype=np.float32)
    assert np.array_equal(a.view(np.uint32), back.view(np.uint32))   # -0.0 included
    # and it is the shortest such text numpy knows of
    for t, v in zip(text, a):
        assert len(t.replace("e+", "e").replace("e-0", "e-")) <= len(repr(float(v))) + 4


def test_shortest_text_examples():
    assert _box2d.format_floats(np.array([0.1, 1.0, 3.1415927, -2.5e-8, 0.0], np.float32)) == \
        ["0.1", "1", "3.1415927", "-2.5e-08", "0"]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_never_reach_a_file(bad):
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    world = build_world(scene)
    bodies, contacts = world.step(scene.dt, 8, 3, record=True)
    bodies["velocity"][5, 1] = bad
    with pytest.raises(ValueError, match="non-finite y in body 5"):
        step_writer(scene, 0, Box2D()).render(0, 0.0, 0.0, bodies, contacts)


def test_render_checks_array_dtypes_and_shapes():
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    world = build_world(scene)
    bodies, contacts = world.step(scene.dt, 8, 3, record=True)
    writer = step_writer(scene, 0, Box2D())
    wrong = dict(bodies, mass=bodies["mass"].astype(np.float64))
    with pytest.raises(TypeError, match="'mass' has dtype float64"):
        writer.render(0, 0.0, 0.0, wrong, contacts)
    short = dict(bodies, omega=bodies["omega"][:-1])
    with pytest.raises(ValueError, match="'omega' has"):
        writer.render(0, 0.0, 0.0, short, contacts)


def test_schema_rejects_nan_text(pile_run, tmp_path):
    src = step_files(pile_run)[-1]
    text = src.read_text()
    bad = tmp_path / "bad.xml"
    bad.write_text(text.replace('<spin omega="', '<spin omega="NaN" x="', 1))
    _, _, errors = schema.validate(bad)
    assert errors and all(e.startswith(f"{bad}:") for e in errors)


@pytest.mark.parametrize("value, valid", [
    ("NaN", False), ("INF", False), ("-INF", False), ("1e39", False), ("-1e39", False), ("1e400", False),
    ("abc", False), ("0x1p3", False), ("", False),
    ("3.4028235e38", True), ("-3.4028235e38", True), ("1e-50", True), ("1.", True), ("+.5e-3", True), (" 1.5 ", True)])
def test_a_number_in_a_step_file_is_a_finite_float32(pile_run, tmp_path, value, valid):
    """The schema's `finite` type (bounds, no longer a pattern: dc validate's largest cost) holds
    exactly the finite float32 values, in the native validator and in xmllint alike."""
    import re
    text = next(pile_run.rglob("step-*.xml")).read_text()
    m = list(re.finditer(r'<position x="([^"]*)"', text))[-1]
    path = tmp_path / "step.xml"
    path.write_text(text[:m.start(1)] + value + text[m.end(1):])
    errors = _box2d.validate_step_file(str(path), _box2d.StepSchema(str(schema.schema_path("step"))), 5)[3]
    assert (not errors) == valid, errors
    if shutil.which("xmllint"):
        lint = subprocess.run(["xmllint", "--noout", "--schema", str(schema.schema_path("step")), str(path)],
                              capture_output=True, text=True)
        assert (lint.returncode == 0) == valid, lint.stderr


def _mutations(text, rng):
    """Edits of a valid step file, each one way of breaking (or keeping) the schema's rules."""
    import re
    tags = [m for m in re.finditer(r"<([a-z_]+)((?:\s+[a-z_]+=\"[^\"]*\")*)\s*/?>", text)]
    values = ["", "abc", "NaN", "INF", "-1", "1e39", "0", "-0", "1.5", "true", "2", "+1", " 7 ", "01", "1.",
              "4294967296", "-2147483649", "face_a", "wobbly", "1e-50", "3.4028235e38", "0x10", "1 2"]
    for _ in range(400):
        m = tags[rng.integers(len(tags))]
        attrs = list(re.finditer(r'([a-z_]+)="([^"]*)"', m.group(2)))
        what = rng.integers(7)
        if what == 0 and attrs:   # a value changed
            a = attrs[rng.integers(len(attrs))]
            start = m.start(2) + a.start(2)
            yield text[:start] + values[rng.integers(len(values))] + text[m.start(2) + a.end(2):]
        elif what == 1 and attrs:   # an attribute removed
            a = attrs[rng.integers(len(attrs))]
            yield text[:m.start(2) + a.start()] + text[m.start(2) + a.end():]
        elif what == 2:   # an attribute added
            yield text[:m.start(2)] + ' bogus="1"' + text[m.start(2):]
        elif what == 3:   # an element added before it
            yield text[:m.start()] + "<bogus/>" + text[m.start():]
        elif what == 4 and m.group(0).endswith("/>"):   # an empty element repeated
            yield text[:m.end()] + m.group(0) + text[m.end():]
        elif what == 5 and m.group(0).endswith("/>"):   # an empty element removed
            yield text[:m.start()] + text[m.end():]
        elif what == 6:   # text where none belongs
            yield text[:m.end()] + "x" + text[m.end():]


def test_the_schemas_table_refuses_what_the_xsd_refuses(pile_run, tmp_path):
    """dc validate checks every file against a table compiled from step.xsd (step/strict.py), the
    XSD itself only where the table refuses a file or leaves it to the XSD: every edit of a real
    step file the XSD refuses the table must refuse too (else a bad file would pass), and it
    refuses nothing the XSD accepts (the schema's own edge cases: test_schema_table.py)."""
    from deepcontact.step.reader import step_schema, strict_table
    rng = np.random.default_rng(7)
    texts = [p.read_text() for p in sorted(pile_run.rglob("step-*.xml"))[::40]]
    path, counts = tmp_path / "step.xml", {"both": 0, "neither": 0}
    for text in texts:
        for edited in _mutations(text, rng):
            path.write_text(edited)
            xsd_valid = not _box2d.validate_step_file(str(path), step_schema(), 1)[3]
            try:
                _box2d.read_step_file(str(path), None, strict_table())
                table_valid = True
            except _box2d.StepFileError as e:
                table_valid = "not valid against the schema" not in e.args[0] and None
            if table_valid is None:   # (refused by the reader's own checks, not the table's: not compared)
                continue
            assert table_valid == xsd_valid, (table_valid, xsd_valid, edited)
            counts["both" if xsd_valid else "neither"] += 1
    assert counts["both"] > 50 and counts["neither"] > 500, counts
