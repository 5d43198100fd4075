"""The files dc trusts are claims, not orders: a replacement journal (.NAME.swap), a lock
file's list of temporary names (.NAME.lock) and an output's record (.dc-output.json) can be
planted by anyone who can put a small file beside an output (an unpacked archive, a shared folder,
a repository). What they name is touched only if it is a name dc itself would have made for that
output, of the right kind, holding dc's record; anything else is left alone and reported in one
line.

The hostile claims are generated: every name in HOSTILE_NAMES in every slot a control file has,
against a folder full of the user's own files (hidden folders, a .git, a file beside the output,
links, a FIFO), which must come out byte for byte as they went in."""
import itertools
import json
import os
import stat
from pathlib import Path

import pytest

from conftest import dc, one_line_error
from deepcontact import output
from deepcontact.errors import InputError

pytestmark = pytest.mark.audit

PILE = ["pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5", "--steps", "5", "-q"]


def users_folder(root):
    """A working folder of a user's own things, beside where an output named `out` will go."""
    (root / ".git" / "objects").mkdir(parents=True)
    (root / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    (root / ".backup").mkdir()
    (root / ".backup" / "paper.tex").write_text("the only copy")
    (root / ".thesis").mkdir()
    (root / ".thesis" / "ch1.tex").write_text("chapter one")
    (root / "thesis.tex").write_text("\\documentclass{book}")
    (root / ".out.partial-1-abc").mkdir()                          # named like ours, no record: the user's
    (root / ".out.partial-1-abc" / "notes.txt").write_text("mine")
    (root / ".out.old-1-abc").mkdir()
    (root / ".out.old-1-abc" / "notes.txt").write_text("mine too")
    (root / ".out.1234.tmp").write_text("a user's file named like a temporary one")
    outside = root.parent / f"{root.name}-outside"
    outside.mkdir(exist_ok=True)
    (outside / "data.csv").write_text("1,2,3\n")
    os.symlink(outside, root / ".out.partial-2-lnk")                 # a link named like ours
    os.symlink(outside, root / ".link")
    os.mkfifo(root / ".out.old-3-fifo")
    return outside


def everything(root, leave_out=lambda rel: False):
    """Every entry under root (links and FIFOs by what they are), with the bytes of each file;
    the entries `leave_out(relative path)` names are not read (a test's 1 GiB sparse journal)."""
    out = {}
    for p in sorted(Path(root).rglob("*")):
        st = os.lstat(p)
        rel = str(p.relative_to(root))
        if leave_out(rel):
            continue
        if stat.S_ISLNK(st.st_mode):
            out[rel] = ("link", os.readlink(p))
        elif stat.S_ISREG(st.st_mode):
            out[rel] = p.read_bytes()
        else:
            out[rel] = "folder" if stat.S_ISDIR(st.st_mode) else "special"
    return out


# Names a planted control file might give: every one must be refused or left alone.
def hostile_names(root):
    return [".", "..", "../..", "/", str(root), str(root / ".git"), ".git", ".backup", ".thesis", "thesis.tex",
            "../x", "out/../.git", ".out.partial-1-abc", ".out.old-1-abc", ".out.partial-2-lnk",
            ".out.old-3-fifo", ".link", ".out.1234.tmp", "", "\x00", ".out.partial-", 7, None, ["x"]]


def mine(root, out="out"):
    """The user's part of root: everything but the output and dc's own control files beside it."""
    return everything(root, lambda k: k == out or k.startswith(f"{out}/") or k in (f".{out}.lock", f".{out}.swap"))


@pytest.fixture
def root(tmp_path):
    root = tmp_path / "work"
    root.mkdir()
    outside = users_folder(root)
    yield root
    assert (outside / "data.csv").read_text() == "1,2,3\n"


def a_swap(root, out):
    """Runs what every folder-writing command runs (output.output_folder with --overwrite)."""
    with output.output_folder(out, output.Owned("test output"), overwrite=True, command="simulate") as work:
        (work / "new.txt").write_text("new")


@pytest.mark.parametrize("slot", ["old", "new", "both"])
def test_a_planted_journal_touches_nothing_it_names(root, slot):
    names = hostile_names(root)
    before = mine(root)
    for name in names:
        claims = {"old": ".out.old-9-ok", "new": ".out.partial-9-ok"}
        if slot in ("old", "both"):
            claims["old"] = name
        if slot in ("new", "both"):
            claims["new"] = name
        (root / ".out.swap").write_text(json.dumps(claims))
        cwd = os.getcwd()
        os.chdir(root)
        try:
            a_swap(root, root / "out")
        except InputError as e:   # refused in one line, naming the journal
            assert ".out.swap" in str(e) and "\n" not in str(e)
        finally:
            os.chdir(cwd)
        assert mine(root) == before, name
        (root / ".out.swap").unlink(missing_ok=True)


def test_a_journal_that_is_not_a_file_or_too_large_is_refused_before_any_work(root):
    before = mine(root)
    makers = {"fifo": lambda p: os.mkfifo(p), "link": lambda p: os.symlink(root / ".git", p),
              "folder": lambda p: p.mkdir(), "sparse": lambda p: os.truncate(open(p, "wb").name, 1 << 30),
              "garbage": lambda p: p.write_bytes(b"\xff\x00{not json")}
    for kind, make in makers.items():
        journal = root / ".out.swap"
        make(journal)
        with pytest.raises(InputError, match=r"\.out\.swap"):
            a_swap(root, root / "out")
        assert not (root / "out").exists() and mine(root) == before, kind
        if journal.is_dir() and not journal.is_symlink():
            journal.rmdir()
        else:
            journal.unlink()


def test_a_killed_replacements_own_journal_is_still_finished(root):
    # the real thing: dc's own names, dc's own record: undone as before
    out = root / "out"
    a_swap(root, out)
    old = root / ".out.old-4242-xyz"
    os.replace(out, old)
    (root / ".out.swap").write_text(json.dumps({"old": old.name, "new": ".out.partial-4242-gone",
                                                "old_id": [old.stat().st_dev, old.stat().st_ino], "new_id": None}))
    with pytest.raises(InputError, match="not empty"):
        with output.output_folder(out, output.Owned("test output"), command="simulate"):
            pass
    assert (out / "new.txt").read_text() == "new" and not old.exists() and not (root / ".out.swap").exists()


def test_a_lock_files_list_removes_only_dcs_own_temporaries(root):
    names = hostile_names(root) + [".out.99.tmp"]
    (root / ".out.99.tmp").write_text("a temporary file a killed dc left")
    before = mine(root)
    del before[".out.99.tmp"], before[".out.1234.tmp"]   # (named as dc names its own: removed)
    (root / ".out.lock").write_text(json.dumps(names))
    with output.locked(root / "out"):
        pass
    assert mine(root) == before and not (root / ".out.lock").exists()


@pytest.mark.parametrize("out, args", [
    ("out", ["simulate", *PILE, "-o", "out"]),
    ("out", ["simulate", *PILE[:-3], "--write-scene", "out"]),
    ("out.png", ["render", "STEP", "-q", "-o", "out.png"]),
    ("out.html", ["render", "RUN", "-q", "-o", "out.html"]),
])
def test_a_planted_lock_list_is_left_alone_by_every_command(root, pile_run, out, args):
    step = next(pile_run.glob("seed-*/step-000100.xml"))
    args = [str(step) if a == "STEP" else str(pile_run) if a == "RUN" else a for a in args]
    (root / f".{out}.lock").write_text(json.dumps(["thesis.tex", ".backup", "../x", str(root / ".git")]))
    before = mine(root, out)
    cwd = os.getcwd()
    os.chdir(root)
    try:
        r = dc(*args)
    finally:
        os.chdir(cwd)
    assert r.returncode == 0, r.stderr
    assert mine(root, out) == before


def test_a_records_temporaries_are_relative_names_of_dcs_own(root):
    """Training resumes in place: its record's temporary list is checked, never obeyed blindly."""
    model = root / "model"
    model.mkdir()
    (model / "last.pt").write_bytes(b"weights")
    (model / ".last.pt.77.tmp").write_text("a temporary file a killed dc train left")
    planted = hostile_names(root) + [str(root / "thesis.tex"), "../thesis.tex", ".last.pt.77.tmp",
                                     "sub/../../thesis.tex"]
    planted = [n for n in planted if isinstance(n, str)]
    (model / output.RECORD).write_text(json.dumps({"command": "train", "state": "done", "files": ["last.pt"],
                                                   "temporary": planted}))
    before = mine(root)
    output.InPlace(model, "train")
    after = mine(root)
    assert not (model / ".last.pt.77.tmp").exists()
    assert {k: v for k, v in after.items() if not k.startswith("model")} == \
        {k: v for k, v in before.items() if not k.startswith("model")}
    assert (model / "last.pt").read_bytes() == b"weights"


def test_a_huge_sparse_record_is_refused_without_reading_it(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    with open(folder / output.RECORD, "wb") as f:
        f.truncate(1 << 30)
    assert output.read_record(folder) is None


def test_the_issues_examples_through_dc(root, pile_run):
    """The audit's cases, rerun: one line, nothing lost."""
    cwd = os.getcwd()
    os.chdir(root)
    try:
        before = mine(root)
        for claims, extra in itertools.product(
                [{"new": ".."}, {"old": "."}, {"old": ".git"}, {"old": ".backup", "new": ".thesis"}],
                [[], ["--overwrite"]]):
            (root / ".out.swap").write_text(json.dumps(claims))
            r = dc("simulate", *PILE, "-o", "out", *extra)
            one_line_error(r, ".out.swap")
            assert mine(root) == before and not (root / "out").exists(), claims
            (root / ".out.swap").unlink()
        (root / ".out.swap").write_text(json.dumps({"old": ".backup", "new": ".thesis"}))
        r = dc("rasterize", str(pile_run), "-q", "-o", "out", "--cell", "1", "--smoothing", "1")
        one_line_error(r, ".out.swap")
        (root / ".out.swap").unlink()
        assert mine(root) == before
    finally:
        os.chdir(cwd)


# Every command that writes an output folder, with a small job: (run, dataset, out) -> arguments.
FOLDER_COMMANDS = {
    "simulate": lambda run, data, out: ["simulate", *PILE, "-o", out],
    "rasterize": lambda run, data, out: ["rasterize", run, "-q", "-o", out],
    "evaluate": lambda run, data, out: ["evaluate", run, "--starts", "zero", "--no-budgets", "--no-plots", "-q",
                                        "-o", out],
    "closed loop": lambda run, data, out: ["evaluate", run, "--closed-loop", "--steps", "5", "--starts", "zero",
                                           "--no-plots", "-q", "-o", out],
    "export": lambda run, data, out: ["export", run, "-q", "-o", out],
    "export csv": lambda run, data, out: ["export", run, "--format", "csv", "-q", "-o", out],
    "train": lambda run, data, out: ["train", data, "--epochs", "1", "--width", "4", "--depth", "2", "--no-plots",
                                     "-q", "-o", out],
    "study figures": lambda run, data, out: ["study", "figures", run, "--every", "60", "-q", "-o", out],
    "study engines": lambda run, data, out: ["study", "engines", "--fast", "-q", "-o", out],
    "study frontier": lambda run, data, out: ["study", "frontier", "--fast", "-q", "-o", out],
}
JOURNALS = {"fifo": os.mkfifo, "folder": os.mkdir, "link": lambda p: os.symlink(".git", p),
            "dangling link": lambda p: os.symlink("nowhere", p)}


@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_a_journal_that_is_not_a_file_is_refused_before_any_work_by_every_command(root, run, dataset, command,
                                                                                 monkeypatch):
    monkeypatch.chdir(root)
    before = mine(root)
    for kind, make in JOURNALS.items():
        make(root / ".out.swap")
        r = dc(*FOLDER_COMMANDS[command](run, dataset, root / "out"))
        # the message is the one the checks before any work give ("nothing was done"; at the swap
        # the message would be another): no timing, which a loaded machine makes a coin toss
        one_line_error(r, ".out.swap", "nothing was done")
        assert not (root / "out").exists() and mine(root) == before, kind
        os.rmdir(root / ".out.swap") if kind == "folder" else os.unlink(root / ".out.swap")


@pytest.mark.parametrize("slot", ["old", "new"])
def test_a_journal_naming_a_complete_output_of_dcs_by_name_alone_deletes_nothing(root, slot):
    """A complete output of dc's moved under a name of the swap's (a copy kept as `.out.old-7-x`,
    a folder unpacked beside the output) is not a swap's leftover: the journal names its folders
    by identity too, and a journal that does not (planted, or naming another folder) touches none."""
    out = root / "out"
    a_swap(root, out)
    kept = root / f".out.{'old' if slot == 'old' else 'partial'}-7-x"
    a_swap(root, root / "elsewhere")
    os.replace(root / "elsewhere", kept)   # (a complete output of dc simulate, its record "done")
    assert output.read_record(kept)["state"] == "done"
    claims = {"old": ".out.old-8-y", "new": ".out.partial-8-y", slot: kept.name}
    for ids in ({}, {"old_id": [0, 0], "new_id": [0, 0]}):   # by name alone, or by another folder's identity
        (root / ".out.swap").write_text(json.dumps({**claims, **ids}))
        with pytest.raises(InputError, match="not empty"):
            with output.output_folder(out, output.Owned("test output"), command="simulate"):
                pass
        assert (kept / "new.txt").read_text() == "new" and (out / "new.txt").read_text() == "new", ids
