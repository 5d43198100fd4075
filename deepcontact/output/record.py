"""What an output folder holds, by its own record: which entries are the command's own.

Inside an output folder, ``.dc-output.json`` records the command and every entry it wrote;
nothing is ever taken for the command's own by its name alone. --overwrite replaces a folder only
if that record says the same command wrote every entry in it.
"""
import json
import logging
import os
import stat
from pathlib import Path

from .. import jsontext
from ..errors import InputError
from . import files
from .names import kind, temporary_name

log = logging.getLogger(__name__)

RECORD = ".dc-output.json"
RECORD_MAX = 64 << 20   # bytes: a record lists every file (a 600-step, 1,000-seed run's is about 21 MB)


class Owned:
    """What one kind of output is called (``what``) and, for the reader, what it holds
    (``patterns``); which entries are the command's own is decided by the record the command left
    inside the folder, never by these names."""

    def __init__(self, what, patterns=()):
        self.what = what
        self.patterns = list(patterns)


def entries(folder):
    """Every entry under folder, relative and ``/``-separated, folders ending in ``/``, in sorted
    depth-first order; symbolic links are listed, never followed. Walked with a stack, not by
    recursion (os.walk and rglob recurse): a tree of any depth."""
    def listing(d):
        with os.scandir(d) as it:
            return iter(sorted(((e.name, e.path, e.is_dir(follow_symlinks=False)) for e in it)))
    out, stack = [], [(listing(folder), "")]
    while stack:
        found, rel = stack[-1]
        entry = next(found, None)
        if entry is None:
            stack.pop()
            continue
        name, full, is_dir = entry
        out.append(f"{rel}{name}/" if is_dir else f"{rel}{name}")
        if is_dir:
            stack.append((listing(full), f"{rel}{name}/"))
    return out


def read_record(folder):
    """The record in an output folder: a dict with ``command``, ``state``, ``files`` and
    ``temporary``, or None where there is none (or it is not one of ours)."""
    p = Path(folder) / RECORD
    try:
        st = os.lstat(p)
        if not stat.S_ISREG(st.st_mode) or st.st_size > RECORD_MAX:
            return None
        rec = jsontext.loads(p.read_bytes())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    ok = (isinstance(rec, dict) and isinstance(rec.get("command"), str) and rec.get("state") in ("partial", "done")
          and all(isinstance(rec.get(k), list) and all(isinstance(x, str) for x in rec[k])
                  for k in ("files", "temporary")))
    return rec if ok else None


# What the command says of how it ran, in every record it writes (filled by the layers above: the
# fences plug-in code ran without, "unfenced", where --unfenced allowed it; cleared as a command starts).
remarks = {}


def write_record(folder, command, state, names=(), temporary=()):
    """The record of an output folder (state "partial" while it is built, "done" when whole), with
    the command's remarks."""
    files.write_text(Path(folder) / RECORD, json.dumps({"command": command, "state": state, "files": sorted(names),
                                                        "temporary": sorted(temporary), **remarks}, indent=0) + "\n")


def our_folder(p, empty_ok=False, command=None):
    """p is a real folder (no link) that holds our record (of `command`, where given), or
    (empty_ok) holds nothing."""
    if kind(p) != "folder":
        return False
    rec = read_record(p)
    if rec is not None:
        return command is None or rec["command"] == command
    try:
        return empty_ok and not os.listdir(p)
    except OSError:
        return False


def remove_claimed(folder, name, ours, why):
    """A temporary file a control file claims a killed run left in folder: removed if `name` is
    one dc makes there (ours) and a regular file; anything else left alone, said in one line (why).
    A name that is not ours is never looked up (it may be a path elsewhere, or hold a NUL)."""
    p = folder / name if ours else None
    found = kind(p) if ours else None
    if not ours or found not in ("file", None):
        log.warning("left %s alone: %s", p if ours else repr(name), why)
    elif found == "file":
        log.info("removing %s, left by an interrupted earlier run", p)
        files.remove_quietly(p)


def check_owned_folder(path, command, overwrite, what="folder", hint="use --overwrite to replace it"):
    """Refuses (InputError) to replace the non-empty folder at path unless overwrite is given, its
    record says dc `command` wrote it, completely, and it holds nothing else: --overwrite never
    deletes what the command did not write."""
    path = Path(path)
    if not overwrite:
        raise InputError(f"output folder is not empty; {hint}", path)
    rec, held = read_record(path), entries(path)
    if rec is None or rec["state"] != "done":
        raise InputError(f"not written by dc {command}: refusing to replace {path} (it holds no record "
                         f"{RECORD} of a dc output; remove it yourself or choose another output)",
                         path / held[0].rstrip("/"))
    if rec["command"] != command:
        raise InputError(f"written by dc {rec['command']}, not dc {command}: refusing to replace it", path)
    own = set(rec["files"]) | {RECORD}
    foreign = next((path / r.rstrip("/") for r in held if r not in own), None)
    if foreign is not None:
        raise InputError(f"not written by dc {command}: refusing to replace {path} (--overwrite only "
                         f"replaces a {what} holding nothing but what dc {command} wrote)", foreign)


class InPlace:
    """The record of a folder written in place (training, which resumes from what it wrote), kept
    up to date as files are written: every file is entered before its bytes, so even a killed run
    leaves a record of what it wrote."""

    def __init__(self, folder, command):
        self.folder, self.command = Path(folder), command
        rec = read_record(folder)
        mine = rec is not None and rec["command"] == command
        self.files = set(rec["files"]) if mine else set()
        # temporary files a killed run of ours left: ours to remove
        for name in (rec["temporary"] if mine else ()):
            remove_claimed(self.folder, name, temporary_name(name),
                           f"the record {RECORD} lists it as a temporary file, but it is not one dc writes there")
        self.temporary = set()
        self.save()

    def enter(self, name, tmp):
        """Enters name, about to be written through the temporary file tmp."""
        if name not in self.files or tmp not in self.temporary:
            self.files.add(name)
            self.temporary.add(tmp)
            self.save()

    def save(self, final=False):
        """Writes the record; final: of what is there now, of what we wrote."""
        if final:
            self.files = {f for f in self.files if (self.folder / f).exists()}
            self.temporary = {t for t in self.temporary if (self.folder / t).exists()}
        write_record(self.folder, self.command, "done", self.files, self.temporary)

    def watch(self):
        """Enters every file written in the folder from now on (files.folder_notes)."""
        files.folder_notes[os.path.abspath(self.folder)] = self.enter

    def unwatch(self):
        """Ends watch; the record saved as of what is there now."""
        if self.forget():
            self.save(final=True)

    def forget(self):
        """Ends watch without saving (the folder is being removed); whether it was watched."""
        return files.folder_notes.pop(os.path.abspath(self.folder), None) is not None
