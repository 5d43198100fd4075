"""Compressed runs (dc simulate --compress) go through every reader as plain ones do, and the
readers' -j gives the same answers as one process."""
import csv
import gzip
import json
import shutil
import subprocess

import numpy as np
import pytest

from deepcontact import schema
from deepcontact.grid.dataset import GridDataset

from conftest import HOSTILE_PILE, RUN_READERS, dc, one_line_error, written


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("gz")
    args = ("simulate", *HOSTILE_PILE, "--steps", "120", "--seeds", "0..1")
    return written(base / "plain", *args), written(base / "packed", *args, "--compress")


def test_a_compressed_run_holds_the_plain_run_gzipped_and_is_reproducible(runs, tmp_path):
    plain, packed = runs
    files = sorted(packed.glob("seed-*/step-*.xml.gz"))
    assert len(files) == 240 and not list(packed.glob("seed-*/step-*.xml"))
    for f in files[::20]:
        assert gzip.decompress(f.read_bytes()) == (plain / f.parent.name / f.name[:-3]).read_bytes()
    assert json.loads((packed / "manifest.json").read_text())["compression"] == "gzip"
    assert json.loads((plain / "manifest.json").read_text())["compression"] == "none"
    size = sum(f.stat().st_size for f in files)
    assert size < sum(f.stat().st_size for f in plain.glob("seed-*/step-*.xml")) / 4
    again = written(tmp_path / "again", "simulate", *HOSTILE_PILE, "--steps", "120", "--seeds", "0..1", "--compress")
    assert all(f.read_bytes() == (again / f.relative_to(packed)).read_bytes() for f in files)   # no time inside


def test_every_reader_takes_a_compressed_run(runs, tmp_path):
    plain, packed = runs
    r = dc("validate", str(packed))
    assert r.returncode == 0 and "242 files checked, 0 invalid" in r.stderr, r.stdout + r.stderr
    r = dc("validate", "--replay", str(packed))
    assert r.returncode == 0 and "largest difference 0: exact" in r.stdout
    a = written(tmp_path / "a", "rasterize", str(plain), "--cell", "1", "--smoothing", "1")
    b = written(tmp_path / "b", "rasterize", str(packed), "--cell", "1", "--smoothing", "1")
    for name in ("inputs", "labels", "contact_impulse", "contact_offsets"):
        assert np.array_equal(np.load(a / f"{name}.npy"), np.load(b / f"{name}.npy")), name
    assert GridDataset(b).step_file(5).name.endswith(".xml.gz")
    evaluated = [written(tmp_path / f"r{k}", "evaluate", "--no-plots", str(run), "--starts", "zero,builtin", "--every",
                         "20", "--no-budgets") for k, run in enumerate(runs)]
    rows = [[(r["seed"], r["step"], r["start"], r["iterations"], r["residual"])
             for r in csv.DictReader(open(e / "steps.csv"))] for e in evaluated]
    assert rows[0] == rows[1] and rows[0]


@pytest.mark.skipif(shutil.which("xmllint") is None, reason="xmllint (libxml2-utils) not installed")
def test_xmllint_reads_compressed_step_files(runs):
    steps = sorted(runs[1].glob("seed-*/step-*.xml.gz"))[::30]
    out = subprocess.run(["xmllint", "--noout", "--schema", schema.schema_path("step"), *map(str, steps)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]


def test_a_step_both_plain_and_compressed_is_refused(runs, tmp_path):
    bad = tmp_path / "run"
    shutil.copytree(runs[1], bad)
    step = sorted(bad.glob("seed-000000/step-*.xml.gz"))[10]
    step.with_name(step.name[:-3]).write_bytes(gzip.decompress(step.read_bytes()))
    one_line_error(dc("rasterize", str(bad), "-o", str(tmp_path / "d")), "is there twice")


def test_a_damaged_compressed_step_is_one_line(runs, tmp_path):
    bad = tmp_path / "run"
    shutil.copytree(runs[1], bad)
    step = sorted(bad.glob("seed-000001/step-*.xml.gz"))[-1]
    step.write_bytes(step.read_bytes()[:-40])   # cut: the gzip trailer and some data gone
    for args in (["rasterize", str(bad), "-o", str(tmp_path / "d")], ["validate", "--replay", str(bad)],
                 ["evaluate", "--no-plots", str(bad), "--starts", "zero", "--every", "200", "-o", str(tmp_path / "r")]):
        one_line_error(dc(*args), step)
    r = dc("validate", str(bad))
    assert r.returncode == 1 and str(step) in r.stdout and "Traceback" not in r.stderr


def test_jobs_change_nothing_in_what_validate_and_evaluate_report(runs, tmp_path):
    plain = runs[0]
    bad = tmp_path / "run"
    shutil.copytree(plain, bad)
    victim = sorted(bad.glob("seed-000001/step-*.xml"))[-1]
    victim.write_text(victim.read_text().replace("<impulse n=\"", "<impulse n=\"x", 1))
    one, two = (dc("validate", "-j", j, str(bad)) for j in ("1", "2"))
    assert one.returncode == two.returncode == 1 and one.stdout == two.stdout and str(victim) in one.stdout
    one, two = (dc("validate", "--replay", "-j", j, str(plain)) for j in ("1", "2"))
    assert one.returncode == two.returncode == 0 and one.stdout == two.stdout
    reports = [written(tmp_path / f"e{j}", "evaluate", "--no-plots", str(plain), "--starts", "zero,builtin,prev",
                       "--every", "15", "--no-budgets", "-j", j) for j in ("1", "2")]
    rows = [[(r["seed"], r["step"], r["start"], r["iterations"], r["residual"], r["error"])
             for r in csv.DictReader(open(e / "steps.csv"))] for e in reports]
    assert rows[0] == rows[1] and len({r[0] for r in rows[0]}) == 2


def test_the_manifests_contact_counts_are_checked_against_the_files(runs, tmp_path):
    """dc rasterize sizes a dataset from the manifest's contact points per file, without reading
    the files first; a count that does not match its file is refused, naming the file."""
    bad = tmp_path / "run"
    shutil.copytree(runs[0], bad)
    manifest = json.loads((bad / "manifest.json").read_text())
    counts = manifest["simulations"][1]["file_contact_points"]
    assert len(counts) == 120 and sum(counts) == manifest["simulations"][1]["contact_points"]
    k = max(range(len(counts)), key=lambda i: counts[i])
    counts[k] -= 1
    (bad / "manifest.json").write_text(json.dumps(manifest))
    step = sorted(bad.glob("seed-000001/step-*.xml"))[k]
    one_line_error(dc("rasterize", str(bad), "-o", str(tmp_path / "d")), step, "contact points")
    counts[k] = "many"
    (bad / "manifest.json").write_text(json.dumps(manifest))
    one_line_error(dc("rasterize", str(bad), "-o", str(tmp_path / "d")), "file_contact_points")


@pytest.fixture(scope="module")
def bombs(runs, tmp_path_factory):
    """The compressed run twice, each with one step file a gzip bomb: the step as written, padded
    with 64 MiB of white space (valid XML: a reader that inflated it all would read it) that gzip
    packs into 64 kB, a thousandth. One at a step the manifest counts no contact points for (read
    only to check that count), one at a step with contacts."""
    made = {}
    counts = json.loads((runs[1] / "manifest.json").read_text())["simulations"][0]["file_contact_points"]
    for kind, index in (("contactless", counts.index(0)), ("contacts", 100)):
        assert (counts[index] == 0) == (kind == "contactless")
        run = shutil.copytree(runs[1], tmp_path_factory.mktemp("bomb") / "run")
        step = run / f"seed-000000/step-{index:06d}.xml.gz"
        xml = gzip.decompress(step.read_bytes())
        end = xml.rindex(b"</step>")
        step.write_bytes(gzip.compress(xml[:end] + b" " * (64 << 20) + xml[end:], 9))
        assert step.stat().st_size < 128 << 10
        made[kind] = run, step
    return made


@pytest.mark.parametrize("kind", ["contactless", "contacts"])
@pytest.mark.parametrize("reader", sorted(RUN_READERS))
def test_every_reader_bounds_what_a_compressed_step_inflates_to(bombs, tmp_path, reader, kind):
    run, step = bombs[kind]
    r = dc(*RUN_READERS[reader](run, tmp_path / "out"))
    if reader == "validate":
        assert r.returncode == 1 and "inflates to more than 64 times" in r.stdout + r.stderr, r.stdout + r.stderr
    else:
        one_line_error(r, step.name, "inflates to more than 64 times")
