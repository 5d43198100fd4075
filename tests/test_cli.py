"""The `dc` commands as a user runs them: exit codes, one-line errors, files on disk."""
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from conftest import dc

SMALL = ["--param", "count=30", "--param", "box=16", "--param", "sigma=4"]


def tree_bytes(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(Path(root).rglob("*")) if p.is_file()}


def test_same_seed_gives_byte_identical_files(tmp_path):
    for name in ("a", "b"):
        r = dc("simulate", "pile", *SMALL, "--steps", "120", "--seeds", "4..5", "-q", "-o", str(tmp_path / name))
        assert r.returncode == 0, r.stderr
    a, b = tree_bytes(tmp_path / "a"), tree_bytes(tmp_path / "b")
    assert len(a) == 2 * 121 + 2 and a == b   # the step files, two scenes, the manifest and the record


def test_parallel_jobs_give_the_same_files(tmp_path):
    r1 = dc("simulate", "pile", *SMALL, "--steps", "60", "--seeds", "0..2", "-q", "-o", str(tmp_path / "a"))
    r2 = dc("simulate", "pile", *SMALL, "--steps", "60", "--seeds", "0..2", "-q", "-j", "2",
            "-o", str(tmp_path / "b"))
    assert r1.returncode == r2.returncode == 0
    assert tree_bytes(tmp_path / "a") == tree_bytes(tmp_path / "b")


def test_manifest_and_layout(tmp_path):
    out = tmp_path / "run"
    r = dc("simulate", "pile", *SMALL, "--steps", "150", "--seeds", "0..3", "--shard", "1/2",
           "--skip-contactless", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    sims = manifest["simulations"]
    assert [s["seed"] for s in sims] == [1, 3]
    for s in sims:
        files = sorted((out / s["dir"]).glob("step-*.xml"))
        assert len(files) == s["files"] < 150        # contact-less early steps skipped
        assert (out / s["dir"] / "scene.xml").exists()
    assert manifest["versions"]["box2d"] == "2.4.1" and manifest["dt"] == 0.01


def test_refuses_a_non_empty_output_folder_without_overwrite(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    keep = out / "notes.txt"
    keep.write_text("mine")
    r = dc("simulate", "pile", *SMALL, "--steps", "5", "-o", str(out))
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == [f"dc simulate: error: {out}: output folder is not empty; "
                                             f"use --overwrite to replace it"]
    # --overwrite replaces a run as a whole; a folder holding anything else is not a run to replace
    r = dc("simulate", "pile", *SMALL, "--steps", "5", "--overwrite", "-q", "-o", str(out))
    assert r.returncode == 1 and "not written by dc simulate" in r.stderr and "notes.txt" in r.stderr
    assert keep.read_text() == "mine" and sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_bad_input_is_one_line_without_traceback(tmp_path):
    bad_scene = tmp_path / "bad.xml"
    bad_scene.write_text('<scene name="x" format="1"><world dt="-1" steps="3"/><effects/><bodies/></scene>')
    cases = [
        (["simulate", "piles", "-o", str(tmp_path / "o1")], "neither a scene file nor a generator", 1),
        # (--param values are option values: exit 2, naming the option)
        (["simulate", "pile", "--param", "radius=big", "-o", str(tmp_path / "o2")], "is not a number", 2),
        (["simulate", "pile", "--param", "nope=1", "-o", str(tmp_path / "o3")], "no parameter 'nope'", 2),
        (["simulate", str(bad_scene), "-o", str(tmp_path / "o4")], f"{bad_scene}:1:", 1),
        (["simulate", "pile", "-o", "/proc/nope"], "cannot write there", 1),
    ]
    for args, expected, code in cases:
        r = dc(*args)
        assert r.returncode == code, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0], (args, r.stderr)
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "o4").exists()
    r = dc("simulate", "pile", "--seeds", "9..2", "-o", str(tmp_path / "o5"))   # a bad option value: exit 2
    assert r.returncode == 2 and "--seeds" in r.stderr and "Traceback" not in r.stderr
    r = dc("simulate", "pile", "--seed", "0..1", "-o", str(tmp_path / "o5"))   # one seed's option given several
    assert r.returncode == 2 and "use --seeds 0..1" in r.stderr and "Traceback" not in r.stderr
    r = dc("simulate", "piles", "-v", "-o", str(tmp_path / "o6"))
    assert r.returncode == 1 and "Traceback" in r.stderr


def test_validate_accepts_a_run_and_pinpoints_a_corrupted_copy(pile_run, tmp_path):
    r = dc("validate", str(pile_run))
    assert r.returncode == 0, r.stdout
    assert "151 files checked, 0 invalid" in r.stderr
    src = sorted(pile_run.glob("seed-*/step-*.xml"))[-1]
    lines = src.read_text().splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if "<impulse " in line)
    lines[k] = lines[k].replace('n="', 'n="-nan', 1)
    bad = tmp_path / "corrupt.xml"
    bad.write_text("".join(lines))
    truncated = tmp_path / "truncated.xml"
    truncated.write_bytes(src.read_bytes()[:5000])
    r = dc("validate", str(bad), str(truncated), str(src))
    assert r.returncode == 1
    assert f"{bad}:{k + 1}:" in r.stdout
    assert f"{truncated}:" in r.stdout
    assert str(src) not in r.stdout
    assert "3 files checked, 2 invalid" in r.stderr


def test_write_scene_then_simulate_it(tmp_path):
    scene = tmp_path / "stack.xml"
    assert dc("simulate", "stack", "--param", "count=4", "--write-scene", str(scene)).returncode == 0
    assert dc("validate", str(scene)).returncode == 0
    r = dc("simulate", "stack", "--param", "count=4", "--write-scene", str(scene))
    assert r.returncode == 1 and "--overwrite" in r.stderr
    r = dc("simulate", str(scene), "--steps", "10", "-q", "-o", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "run").glob("seed-*/step-*.xml"))) == 10


def test_every_command_has_examples_in_its_help():
    for cmd in ("simulate", "validate"):
        r = dc(cmd, "--help")
        assert r.returncode == 0 and "Examples:" in r.stdout


def test_list_generators():
    r = dc("simulate", "--list", "pile")
    assert r.returncode == 0 and "pile: count=100" in r.stdout and "warm-start-energy:" in r.stdout


def test_ctrl_c_leaves_nothing_of_an_unfinished_run(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "deepcontact.cli.main", "simulate", "pile", "--seeds", "0..50", "-q",
           "-o", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    # the run is built in a partial folder beside OUTDIR and appears only when complete
    while time.time() < deadline and len(list(tmp_path.glob(".run.partial-*/seed-*/step-*.xml"))) < 200:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []      # no run, no partial folder, no lock file


def test_off_a_terminal_a_long_run_says_where_it_is(tmp_path, monkeypatch):
    """Logged to a file, Make or CI, a run is not silent: a line every DC_PROGRESS_EVERY seconds
    (30 by default) with what is done, the rate and what is left, and one at its end; -q says
    nothing (here every update is "long": the period is 0)."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")
    r = dc("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5", "--steps", "20",
           "-o", tmp_path / "run")
    assert r.returncode == 0, r.stderr
    lines = [x for x in r.stderr.splitlines() if x.startswith("dc simulate pile: ")]
    assert len(lines) >= 20 and "/20 steps (" in lines[0] and "steps/s, about" in lines[1], r.stderr   # (from 2 steps)
    assert lines[-1].startswith("dc simulate pile: 20/20 steps (100%) done in "), lines[-1]
    r = dc("simulate", "pile", "--param", "count=12", "--steps", "20", "-q", "-o", tmp_path / "quiet")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    monkeypatch.setenv("DC_PROGRESS_EVERY", "30")   # (the default: a short run says nothing)
    r = dc("simulate", "pile", "--param", "count=12", "--steps", "20", "-o", tmp_path / "short")
    assert r.returncode == 0 and "steps/s" not in r.stderr, r.stderr


def test_training_says_where_it_is_in_every_epoch_and_within_a_long_one(dataset, tmp_path, monkeypatch):
    """dc train printed "epoch N: loss" and nothing else: not how many epochs are left, nor a word
    within an epoch however long (here every batch is "long": the period is 0); within one, epoch
    1's line gave no rate nor time left: now the samples of the epoch's, the rate, the time left in
    the epoch and in the run."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")
    r = dc("train", dataset, "-o", tmp_path / "m", "--epochs", "2", "--width", "4", "--depth", "2",
           "--batch-size", "10")
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert any(x.startswith("epoch 1 of 2: loss ") and " an epoch, about " in x and x.endswith(" left)")
               for x in lines), r.stderr
    for epoch in (1, 2):
        assert any(x.startswith(f"dc train, epoch {epoch} of 2: ") and " samples (" in x and " samples/s, about " in x
                   and "; the run: about " in x for x in lines), r.stderr
    r = dc("train", dataset, "-o", tmp_path / "q", "--epochs", "2", "--width", "4", "--depth", "2", "-q")
    assert r.returncode == 0 and r.stderr == "", r.stderr
