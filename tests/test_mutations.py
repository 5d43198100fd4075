"""Property: whatever is done to a valid scene file, step file or dataset metadata (attribute
values, integers at the type limits, non-numbers, element order, truncation, JSON of the wrong
type), a command either succeeds with finite output or fails cleanly: exit 1 or 2, one line, no
traceback, and nothing left where its output would have gone.

The commands run in-process through click's runner (the real `dc` commands and their error
handling, without a process start per example); the same contract through real processes is
tests/test_nothing_lost.py. The suite runs a fixed set of examples; `DC_MUTATIONS=400 pytest
tests/test_mutations.py` draws 400 fresh ones for each kind of file.
"""
import json
import os
import re
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings, strategies as st

from conftest import dc
from deepcontact.cli.main import cli

PILE = ["pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5"]
SETTINGS = settings(max_examples=int(os.environ.get("DC_MUTATIONS", "30")), deadline=None,
                    derandomize="DC_MUTATIONS" not in os.environ,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# Values a hostile file may hold where a number, a name or a count is expected.
NASTY = st.sampled_from(["", " ", "abc", "-1", "0", "1", "-0", "2147483647", "2147483648", "-2147483649",
                         "4294967296", "99999999999999999999", "1e39", "-1e39", "1e-45", "nan", "NaN", "inf",
                         "-inf", "0x10", "1,5", " 7 ", "&amp;", "true", "\u00e9"])
JSON_NASTY = st.sampled_from([None, -1, 0, 2 ** 31, 2 ** 63, 10 ** 400, 1.5, float("nan"), True, "x", "", [],
                              [1, "a"], {}, {"a": 1}])


def invoke(*args):
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=True)
    finally:
        for s, h in saved.items():
            signal.signal(s, h)


def assert_clean(result, out, allow_report=False):
    """Success, or exit 1/2 with one line and no traceback and no output left."""
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    err = result.stderr
    assert "Traceback" not in err and "Traceback" not in result.stdout, err
    assert result.exit_code in (0, 1, 2), (result.exit_code, err)
    if result.exit_code == 1 and not (allow_report and not err.strip()):
        assert len(err.strip().splitlines()) == 1, err
    if result.exit_code == 2:
        assert "Error:" in err, err
    if out is not None:
        beside = [p.name for p in Path(out).parent.iterdir() if p.name.startswith(f".{Path(out).name}.")]
        assert beside == [], beside
        if result.exit_code != 0:
            assert not Path(out).exists()


def attribute_spans(text):
    return [m.span(2) for m in re.finditer(r'\b([a-z_]+)="([^"]*)"', text)]


@st.composite
def mutated_xml(draw, text):
    kind = draw(st.sampled_from(["value", "value", "value", "swap", "drop", "truncate"]))
    lines = text.splitlines(keepends=True)
    if kind == "value":
        spans = attribute_spans(text)
        a, b = spans[draw(st.integers(0, len(spans) - 1))]
        return text[:a] + draw(NASTY) + text[b:]
    if kind == "swap":
        i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
        return "".join(lines)
    if kind == "drop":
        del lines[draw(st.integers(0, len(lines) - 1))]
        return "".join(lines)
    return text[:draw(st.integers(0, len(text) - 1))]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("mutations")
    run = root / "run"
    assert dc("simulate", *PILE, "--steps", "90", "--skip-contactless", "-q", "-o", str(run)).returncode == 0
    scene = root / "scene.xml"
    assert dc("simulate", *PILE, "--steps", "5", "--write-scene", str(scene)).returncode == 0
    data = root / "data"
    assert dc("rasterize", str(run), "-o", str(data), "--cell", "1", "--smoothing", "1", "-q").returncode == 0
    return root


@SETTINGS
@given(data=st.data())
def test_a_mutated_scene_file_is_simulated_or_refused_cleanly(base, tmp_path, data):
    text = (base / "scene.xml").read_text()
    scene = tmp_path / "scene.xml"
    scene.write_text(data.draw(mutated_xml(text)))
    out = tmp_path / "out"
    result = invoke("simulate", scene, "--steps", "3", "-q", "-o", out)
    assert_clean(result, out)
    if result.exit_code == 0:
        shutil.rmtree(out)


@SETTINGS
@given(data=st.data())
def test_a_mutated_step_file_is_read_or_refused_cleanly(base, tmp_path, data):
    step = sorted((base / "run").glob("seed-*/step-*.xml"))[-1]
    original = step.read_bytes()
    try:
        step.write_text(data.draw(mutated_xml(original.decode())))
        out = tmp_path / "data"
        result = invoke("rasterize", base / "run", "-o", out, "--cell", "1", "--smoothing", "1", "-q")
        assert_clean(result, out)
        if result.exit_code == 0:
            assert np.all(np.isfinite(np.load(out / "inputs.npy"))) and np.all(np.isfinite(np.load(out / "labels.npy")))
            shutil.rmtree(out)
        assert_clean(invoke("validate", "--replay", "-q", base / "run"), None, allow_report=True)
    finally:
        step.write_bytes(original)


def json_paths(value, path=()):
    yield path
    if isinstance(value, dict):
        for k, v in value.items():
            yield from json_paths(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value[:3]):
            yield from json_paths(v, path + (i,))


@SETTINGS
@given(data=st.data())
def test_mutated_metadata_is_trained_on_or_refused_cleanly(base, tmp_path, data):
    meta_path = base / "data" / "metadata.json"
    original = meta_path.read_bytes()
    meta = json.loads(original)
    paths = [p for p in json_paths(meta) if p]
    path = data.draw(st.sampled_from(paths))
    holder = meta
    for key in path[:-1]:
        holder = holder[key]
    if data.draw(st.booleans()):
        holder[path[-1]] = data.draw(JSON_NASTY)
    elif isinstance(holder, dict):
        del holder[path[-1]]
    else:
        holder.pop(path[-1])
    try:
        meta_path.write_text(json.dumps(meta))
        out = tmp_path / "model"
        result = invoke("train", base / "data", "-o", out, "--epochs", "1", "--width", "4", "--depth", "2",
                        "--no-plots", "-q")
        assert_clean(result, out)
        if result.exit_code == 0:   # (tmp_path is shared by the examples)
            shutil.rmtree(out)
    finally:
        meta_path.write_bytes(original)
