"""A study's finished units of work, kept so that a stopped study resumes where it stopped.

A fenced study with an output (`dc study NAME -o OUT`, fence.py) is given a folder beside that
output, ``.OUT.units``, which outlives the run. The study keeps there each unit of work it
finishes (one setting measured on one scene, ...): one file a unit, written atomically, named by a
hash of everything that decides the unit's result: the study, the versions of what it measures
with, a hash of the code (deepcontact's and the study's own modules and native libraries), the
conditions it was timed under (the worker processes, -j: units timed side by side are not timed
alone), and the unit's own settings. A stopped run (Ctrl-C, SIGTERM, a crash, a kill) publishes nothing and
leaves the folder; the same command with --resume reuses the units whose key is the same and
measures the rest, so that its output is the uninterrupted run's (timings apart: a unit kept
keeps the times it was measured with). Once the output is published whole, dc's process removes
the folder. While it holds units, a run without --resume refuses to start (--overwrite measures
everything again), as `dc train` refuses a folder that holds a run.

A study keeps its units with two calls:

    with units.keeping("study engines", resume, overwrite, code=[dcstudies], conditions={"jobs": jobs}):
        row = units.kept({"scene": case, "setting": setting}, lambda: measure(case, setting), Row)

kept() may be called from the study's worker processes (forked inside `keeping`). A value goes
through its file's JSON (dataclasses of plain fields, lists, dicts, numbers, strings) whether it
was measured now or read back, so a resumed run and an uninterrupted one return the same values.
"""
import dataclasses
import hashlib
import json
import logging
import os
import re
import stat
from contextlib import contextmanager
from pathlib import Path

from .. import jsontext, output
from ..errors import InputError, OptionError, count
from ..output.names import beside, kind
from ..regular import read_regular

log = logging.getLogger("deepcontact.studies")

ENV = "DC_STUDY_UNITS"   # the folder a fenced study keeps its units in (set by dc's process)
UNIT = re.compile(r"[0-9a-f]{64}\.json")
TALLY = "tally"          # a line per unit reused or measured (appended: the workers' counts)
UNIT_MAX = 1 << 20       # bytes: a unit file is a row or a few
_CODE_SUFFIXES = (".py", ".so")

_journal = None          # the Journal of the study running in this process (keeping)
_measured = 0            # units this process measured (not read back): measured()


# --- dc's side: the folder beside the output ---------------------------------------------------------

class Beside:
    """dc's side (under the output's lock): the units folder beside a fenced study's output, made
    where missing; what the study may write (`writable`) and is told (`env`); removed once the
    output is published (published()), or at the end when it holds nothing."""

    def __init__(self, target):
        self.target, self.folder = target, beside(target, "units")

    def __enter__(self):
        found = kind(self.folder)
        if found not in (None, "folder"):
            raise InputError(f"{self.folder.name} beside it, where a stopped study keeps its finished units, is not "
                             f"a folder (a link, file or device): nothing was done; remove it", self.target)
        try:
            self.folder.mkdir(exist_ok=True)
        except OSError as e:
            raise InputError(f"cannot keep a study's finished units beside it: {e.strerror or e}",
                             self.folder) from None
        return self

    @property
    def writable(self):
        return [str(self.folder)]

    @property
    def env(self):
        return {ENV: str(self.folder)}

    def published(self):
        """The output is whole and in place: its units have served."""
        output.remove_tree_quietly(self.folder)

    def __exit__(self, stopped, *exc):
        try:
            self.folder.rmdir()   # (only where empty: a stop before the first unit leaves nothing)
        except OSError:
            found = units_in(self.folder)
            if stopped is not None and found:   # (a stop or a crash: say what it keeps, and how to use it)
                log.warning("%s: %s of the stopped study kept; the same command with --resume reuses them",
                            self.folder, count(len(found), "finished unit"))
        return False


# --- the study's side ----------------------------------------------------------------------------------

def units_in(folder):
    """The unit files in a units folder (by name)."""
    try:
        return sorted(n for n in os.listdir(folder) if UNIT.fullmatch(n))
    except OSError:
        return []


class Journal:
    """The units of one study run: kept(key, compute, as_type) reads a unit's file or measures it
    and writes one; tally() counts what this run reused and measured (all its processes)."""

    def __init__(self, folder, study, code=(), conditions=None):
        from ..protocol import protocol   # (it loads the native module: kept off dc's start, which imports this)
        self.folder, self.study, self.conditions = Path(folder), study, plain(conditions or {})
        self.versions = protocol()["versions"]
        self.code = code_hash(code)
        self.tally_from = _size(self.folder / TALLY)

    def key(self, unit):
        """(the file name of a unit, its whole key as JSON text)."""
        whole = {"study": self.study, "versions": self.versions, "code": self.code, "conditions": self.conditions,
                 "unit": plain(unit)}
        text = json.dumps(whole, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest() + ".json", text

    def kept(self, unit, compute, as_type=None):
        """The unit's value read back from its file, or compute()'s, written to its file first
        (module kept())."""
        name, key = self.key(unit)
        found = self._read(self.folder / name, key, as_type)
        if found is not _MISSING:
            self._count("reused")
            return found
        value = plain(compute())
        output.write_text(self.folder / name, json.dumps({"key": json.loads(key), "value": value}) + "\n")
        self._count("measured")
        return restored(value, as_type)

    def _read(self, path, key, as_type):
        """The value kept in path for key, or _MISSING (no such file, another key, or not one this
        module wrote: then measured again and written over)."""
        raw = read_regular(path, UNIT_MAX)
        if raw is None:
            return _MISSING
        try:
            data = jsontext.loads(raw)
            if json.dumps(data["key"], sort_keys=True, separators=(",", ":")) != key:
                return _MISSING
            return restored(data["value"], as_type)
        except (OSError, ValueError, TypeError, KeyError):
            return _MISSING

    def _count(self, what):
        """One line in the tally, appended (whole lines from any process: O_APPEND); a tally that
        cannot be written (not a regular file of ours) counts nothing, and costs no unit."""
        try:
            fd = os.open(self.folder / TALLY, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK,
                         0o644)
        except OSError:
            return
        try:
            if stat.S_ISREG(os.fstat(fd).st_mode):
                os.write(fd, f"{what}\n".encode())
        finally:
            os.close(fd)

    def tally(self):
        """{"reused": n, "measured": n} of this run."""
        raw = read_regular(self.folder / TALLY, 64 << 20) or b""
        lines = raw[self.tally_from:].decode(errors="replace").split()
        return {what: lines.count(what) for what in ("reused", "measured")}


_MISSING = object()


@contextmanager
def keeping(study, resume=False, overwrite=False, code=(), conditions=None):
    """The units of the study run in this block, kept (kept()) where dc's process gave it a
    folder (a fenced study with -o); elsewhere kept() just measures. Refuses to start over the
    units a stopped run kept unless resume (reuse them) or overwrite (remove them) says which;
    resume without a folder is a bad option. code: the study's own packages (modules or
    folders), whose code is part of every unit's key; conditions: what the units are timed under
    and no unit's settings say ({"jobs": worker processes}), part of every unit's key too."""
    global _journal
    folder = os.environ.get(ENV)
    if not folder:
        if resume:
            raise OptionError("--resume reuses what a stopped run kept beside its output: give the output (-o) "
                              "the stopped run wrote to", "--resume")
        yield None
        return
    found = units_in(folder)
    _check_start(Path(folder), study, found, resume, overwrite)
    _journal = Journal(folder, study, code, conditions)
    try:
        yield _journal
        _said(_journal, resume, len(found))
    finally:
        _journal = None


def _check_start(folder, study, found, resume, overwrite):
    """What a run does with the units a stopped one kept: refused without resume or overwrite;
    removed with overwrite alone; said with resume."""
    if resume:
        log.info("resuming: %s kept beside the output by a stopped run (%s); those measured with these options "
                 "are reused", count(len(found), "finished unit"), folder.name)
        return
    if found and not overwrite:
        raise InputError(f"a stopped run of dc {study} kept {count(len(found), 'finished unit')} of work here: "
                         f"--resume reuses those measured with the same options, --overwrite measures "
                         f"everything again", folder)
    for name in found + [TALLY]:
        try:
            os.unlink(folder / name)
        except FileNotFoundError:
            pass


def _said(journal, resume, found):
    """The line a resumed run ends its work with: what it reused and what it measured."""
    if resume:
        t = journal.tally()
        other = (f"; the other {found - t['reused']:,} kept were measured with other options, other code or "
                 f"another number of worker processes (-j), and "
                 f"not reused" if t["reused"] < found else "")
        log.info("kept units: %s reused, %s measured now%s", count(t["reused"], "unit"),
                 count(t["measured"], "unit"), other)


def kept(unit, compute, as_type=None):
    """compute()'s value for the unit of work `unit` (a dict of everything that decides it:
    dataclasses, lists, dicts, numbers, strings), read back where this run's study kept it
    (keeping), else measured and kept; as_type: the dataclass the value is (its fields plain
    values), to make it again from its file."""
    journal = _journal
    if journal is None:
        return _measuring(compute)
    return journal.kept(unit, lambda: _measuring(compute), as_type)


def _measuring(compute):
    global _measured
    _measured += 1
    return compute()


def measured() -> int:
    """How many units this process has measured, not read back: a study's progress tells a
    resumed run's reused units (done before it, no part of its rate) from those it measures."""
    return _measured


# --- values and keys as JSON ----------------------------------------------------------------------------

def plain(value):
    """value as JSON's values: a dataclass as the dict of its fields, tuples as lists, numpy
    scalars as Python's; TypeError for anything else (it would not come back the same)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value.item() if hasattr(value, "item") else value
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return {k: plain(v) for k, v in value.items()}
    if hasattr(value, "item") and hasattr(value, "dtype") and getattr(value, "shape", None) == ():
        return value.item()
    raise TypeError(f"a unit of work cannot keep a {type(value).__name__}")


def restored(value, as_type):
    """A kept value made again: as_type(**fields) for a dataclass (TypeError where the fields
    are not its own)."""
    if as_type is None:
        return value
    names = [f.name for f in dataclasses.fields(as_type)]
    if not isinstance(value, dict) or sorted(value) != sorted(names):
        raise TypeError(f"not the fields of {as_type.__name__}")
    return as_type(**value)


def code_hash(packages=()):
    """A hash of the code that measures: every module and native library of deepcontact and of
    `packages` (modules or folders), by path and content."""
    import deepcontact   # (the package's own folder; imported by its name: this module is inside it)
    h = hashlib.sha256()
    for root in [deepcontact, *packages]:
        root = Path(getattr(root, "__file__", None) or root)
        root = root.parent if root.is_file() else root
        for path in sorted(p for p in root.rglob("*") if p.suffix in _CODE_SUFFIXES and p.is_file()):
            h.update(str(path.relative_to(root.parent)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def _size(path):
    try:
        return os.path.getsize(path)
    except OSError:
        return 0
