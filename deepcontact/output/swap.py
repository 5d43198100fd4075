"""An output folder built beside its place and swapped in whole, by a journalled replacement.

The output is built in ``.NAME.partial-*``; when complete the journal ``.NAME.swap`` names the
earlier output while it is moved aside to ``.NAME.old-*``, and the new one is renamed into place.
The swap is held against stop signals; a process killed in the middle of it is finished or undone
by the next command on that output (`recover`). An empty folder the user made for the output is
kept instead: the output's entries are renamed into it, its record last (the journal says "fill").
"""
import errno
import json
import logging
import os
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path

from .. import interrupts, jsontext
from ..errors import InputError
from . import files, lock, record
from .names import beside, kind, own_name, short_name
from .record import RECORD, entries, our_folder, read_record
from .trees import remove_tree_quietly

log = logging.getLogger(__name__)

JOURNAL_MAX = 4096      # bytes: a journal names two folders

# Outputs swapped in during this process: an interruption that comes after is said as such.
completed = []

# Partial folders this process is building: what a hard stop removes.
_building = set()


def _identity(p):
    """A folder's (device, inode): a rename keeps it, and a journal names its folders by it as
    well as by name, so that another folder put under one of those names is never taken for it."""
    st = os.lstat(p)
    return [st.st_dev, st.st_ino]


def _is(p, identity):
    """Whether the folder at p is the one a journal named by `identity` (a [device, inode] pair)."""
    if not (isinstance(identity, list) and len(identity) == 2 and all(type(v) is int for v in identity)):
        return False
    try:
        return _identity(p) == identity
    except OSError:
        return False


def _keep_attributes(folder, onto):
    """The user's folder's mode, group and extended attributes onto the folder that replaces it (a
    colleague's group, a setgid bit, an ACL or a label set on an empty output folder stay). What
    this user may not set is left as it is."""
    st = os.lstat(folder)
    os.chmod(onto, stat.S_IMODE(st.st_mode))
    for owner in (st.st_uid, -1):   # (its owner too where this user may set it: root)
        try:
            os.chown(onto, owner, st.st_gid)
            os.chmod(onto, stat.S_IMODE(st.st_mode))   # (chown clears a setgid bit: set it again)
            break
        except OSError:
            pass
    try:
        names = os.listxattr(folder, follow_symlinks=False)
    except OSError:
        return
    for name in names:
        try:
            os.setxattr(onto, name, os.getxattr(folder, name, follow_symlinks=False), follow_symlinks=False)
        except OSError:
            pass


def recover(path, command=None):
    """Finishes or undoes what a killed earlier command left beside path (called under its lock,
    so no running command owns any of it): a replacement cut between its renames is undone (the
    earlier output restored) or, when the new output is in place, finished; partial folders that
    hold our record (of `command`, where given) are removed. Nothing without our record or journal is
    touched, and a journal or record is a claim, checked, never an order (own_name, _read_journal)."""
    path = Path(path)
    journal = beside(path, "swap")
    claims = _read_journal(journal, path)
    if claims is not None:
        _finish_or_undo(path, claims, journal, command)
        files.remove_quietly(journal)
    for p in path.parent.iterdir() if path.parent.is_dir() else ():
        if own_name(path, "partial", p.name) and our_folder(p, command=command):
            if read_record(p)["state"] == "partial":
                log.info("removing %s, left by an interrupted earlier run", p)
                remove_tree_quietly(p)


def _finish_or_undo(path, claims, journal, command):
    """The replacement a journal names, finished or undone."""
    if claims.get("fill") is True:
        _finish_or_undo_fill(path, claims, journal, command)
        return
    old, new = (path.parent / claims[k] for k in ("old", "new"))
    # each the very folder the journal named (by identity, not only by name and record: a
    # complete output of dc's moved under one of those names is not a swap's leftover)
    old_ours = our_folder(old, empty_ok=True, command=command) and _is(old, claims.get("old_id"))
    new_ours = our_folder(new, command=command) and _is(new, claims.get("new_id"))
    if not os.path.lexists(path) and old_ours:
        # killed between the renames: the earlier output is the only copy, and comes back
        os.replace(old, path)
        log.warning("restored %s from %s: an earlier replacement was interrupted before the new output "
                    "was in place", path, old.name)
    elif old_ours:
        # killed after the swap, while the earlier output was being removed
        log.info("removing %s, the output an interrupted replacement had already replaced", old)
        remove_tree_quietly(old)
    if new_ours:   # never swapped in: ours, unfinished
        log.info("removing %s, left by an interrupted earlier run", new)
        remove_tree_quietly(new)
    for p, ours in ((old, old_ours), (new, new_ours)):
        if not ours and os.path.lexists(p) and p != path:
            log.warning("left %s alone: the journal %s names it, but it is not the folder the journal "
                        "wrote of (no record of dc's, or another folder under that name)", p, journal.name)


def _empty_folder(path):
    """Whether path is a folder (not a link) holding nothing: one a user made for the output."""
    return kind(path) == "folder" and not os.listdir(path)


def _fill(tmp, path):
    """The finished output's entries moved from tmp into the empty folder path, each by a rename,
    its record last (until then path holds no record, and the next run moves them back)."""
    names = sorted(os.listdir(tmp), key=lambda name: name == RECORD)
    for name in names:
        if os.path.lexists(path / name):   # (put there since the check: a rename would replace it)
            raise OSError(errno.EEXIST, "appeared in the output folder during the run", str(path / name))
        os.rename(tmp / name, path / name)


def _unfill(tmp, path):
    """What _fill moved into path (the entries tmp's record lists, and the record), moved back."""
    rec = read_record(tmp) or read_record(path)
    moved = {entry.split("/")[0] for entry in (rec or {}).get("files", [])} | {RECORD}
    for name in moved:
        if os.path.lexists(path / name) and not os.path.lexists(tmp / name):
            os.rename(path / name, tmp / name)


def _finish_or_undo_fill(path, claims, journal, command):
    """A filling of the user's empty folder (_fill) a killed run left: finished where its record
    is in place, else every entry it moved goes back, and the partial folder is removed; path is
    the user's folder again, empty, or the whole output."""
    new = path.parent / claims["new"]
    same = _is(path, claims.get("old_id")) and _is(new, claims.get("new_id"))
    done = read_record(path)
    if same and not (done and done["state"] == "done" and (command is None or done["command"] == command)):
        if our_folder(new, command=command):
            _unfill(new, path)
            log.warning("undid the filling of %s that an interrupted run began: it is empty again", path)
    elif not same:
        log.warning("left %s alone: the journal %s names it, but it is not the folder the journal wrote of",
                    new, journal.name)
        return
    if our_folder(new, empty_ok=True, command=command):
        remove_tree_quietly(new)


def _read_journal(journal, path):
    """The folders a journal beside path names, {"old": name, "new": name}, or None if there is no
    journal. One that is not a regular file, or does not name two folders of the kinds `folder`
    makes for path, is refused (InputError) and left as it is: nothing it names is touched."""
    found = kind(journal)
    if found is None:
        return None
    refuse = f"the journal {journal.name} beside it"
    if found != "file":
        raise InputError(f"{refuse} is not a regular file (a link, folder, FIFO or device): nothing was done; "
                         f"remove it", path)
    try:
        fd = os.open(journal, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        try:
            data = os.read(fd, JOURNAL_MAX + 1) if stat.S_ISREG(os.fstat(fd).st_mode) else None
        finally:
            os.close(fd)
        claims = jsontext.loads(data) if data is not None and len(data) <= JOURNAL_MAX else None
    except OSError as e:
        if e.errno == errno.ENOENT:
            return None
        raise InputError(f"{refuse} cannot be read: {e.strerror or e}; nothing was done", path) from None
    except (ValueError, UnicodeDecodeError):
        claims = None
    if not (isinstance(claims, dict) and own_name(path, "old", claims.get("old"))
            and own_name(path, "partial", claims.get("new"))):
        what = {k: claims.get(k) for k in ("old", "new")} if isinstance(claims, dict) else "no two folders"
        raise InputError(f"{refuse} is not one dc wrote (it names {what}, not folders dc makes for "
                         f"{path.name}): nothing it names was touched; remove it", path)
    return claims


class _Swap:
    """One replacement: the partial folder it builds, and what it did, for undoing it where it
    fails half-way."""

    def __init__(self, path):
        self.path, self.tmp, self.built, self.old = path, None, None, None
        self.before, self.journalled, self.swapped, self.fill = None, False, False, False

    def start(self, command):
        """The partial folder beside path, made, held and recorded as ours."""
        path = self.path
        # held: a stop signal between making the folder and owning it would leave it behind
        with interrupts.held():
            try:
                self.tmp = tmp = Path(tempfile.mkdtemp(prefix=f".{short_name(path.name)}.partial-{os.getpid()}-",
                                                       dir=path.parent))
                _building.add(tmp)
                self.built = files.hold_root(tmp)
                os.chmod(tmp, 0o777 & ~files.umask())   # the output's own mode: mkdtemp's 0700 is for secrets
                record.write_record(tmp, command, "partial")
            except OSError as e:
                raise InputError(f"cannot write there: {e.strerror or e}", path) from None
        self.old = tmp.with_name(tmp.name.replace(".partial-", ".old-", 1))   # (unique as tmp's name is)
        return tmp

    def run(self, command):
        """The journal, then the earlier output moved aside and the new one renamed into place."""
        path, tmp = self.path, self.tmp
        # the journal first: from here on, a kill at any instruction is finished or undone by
        # the next command (recover), which finds the earlier output or the new one, whole
        self.before = _identity(path) if os.path.lexists(path) else None
        self.fill = self.before is not None and _empty_folder(path)
        files.write_text(beside(path, "swap"), json.dumps({
            "old": self.old.name, "new": tmp.name, "new_id": _identity(tmp), "old_id": self.before,
            **({"fill": True} if self.fill else {})}) + "\n")
        self.journalled = True
        record.write_record(tmp, command, "done", [r for r in entries(tmp) if r != RECORD])
        if self.fill:   # the user's own empty folder is kept (its owner, mode, inode): filled, not replaced
            _fill(tmp, path)
            self.swapped = True
            completed.append(path)
            os.rmdir(tmp)
            files.remove_quietly(beside(path, "swap"))
            return
        if os.path.lexists(path):
            _keep_attributes(path, tmp)
            os.replace(path, self.old)
        os.replace(tmp, path)
        self.swapped = True
        completed.append(path)
        if self.old.exists():
            remove_tree_quietly(self.old)
        files.remove_quietly(beside(path, "swap"))

    def undo(self):
        """Undone here as far as it can be (a full disk or a file system gone read-only in the
        swap), so that nothing is left for the next run to finish or undo."""
        path, tmp, old = self.path, self.tmp, self.old
        if tmp is None:
            return
        try:
            if self.fill and _is(path, self.before) and _is(tmp, self.built):
                _unfill(tmp, path)
            if old is not None and os.path.lexists(old) and not os.path.lexists(path) and _is(old, self.before):
                os.replace(old, path)
            if _is(tmp, self.built):
                remove_tree_quietly(tmp)
            if self.journalled and not os.path.lexists(tmp) and not os.path.lexists(old):
                files.remove_quietly(beside(path, "swap"))
        except OSError:   # (what is left, the journal names: the next run finishes or undoes it)
            pass


@contextmanager
def folder(path, command="dc"):
    """A temporary folder beside `path` that becomes `path` only if the block completes.

    The swap is journalled (``.NAME.swap`` names the earlier output while it is moved aside) and
    held against stop signals, which are raised once it is done; a process killed in the middle is
    finished or undone by `recover`. On failure, Ctrl-C or a signal before the swap the temporary
    folder is removed and `path` is left as it was."""
    path = Path(path)
    # the swap's own names must be free before any work, not found taken at its end (recover has
    # finished or refused whatever an earlier run left; anything there now, a link, a FIFO, a
    # folder, was put there since, or by a caller that did not recover)
    journal = beside(path, "swap")
    if os.path.lexists(journal):
        raise InputError(f"the journal {journal.name} beside it is there before this run began its work (a "
                         f"{kind(journal) or 'file'}): nothing was done; remove it", path)
    swap = _Swap(path)
    try:
        tmp = swap.start(command)
        yield tmp
        if not _is(tmp, swap.built):   # (what is there now is not what this run built: swap in nothing)
            raise InputError(f"the output being built, {tmp.name}, was moved or replaced during the run (by a link "
                             f"or another folder): nothing was swapped in, and {path.name} is as it was", path)
        with interrupts.held():
            swap.run(command)
    except BaseException:
        if not swap.swapped:
            swap.undo()
        raise
    finally:
        _building.discard(swap.tmp)
        if swap.tmp is not None:
            files.release_root(swap.tmp)


def hold_building(folder, command):
    """A folder this process just made beside an output, held as a partial output of dc `command`:
    a hard stop removes it, and so does the next command on that output (recover) if this process
    is killed."""
    _building.add(Path(folder))
    record.write_record(folder, command, "partial")


def release_building(folder):
    """Ends hold_building (the folder was swapped in or removed)."""
    _building.discard(Path(folder))


def _abandon():
    """What unwinding would remove, removed from another thread while the main thread is stuck in
    a plug-in that swallowed the stop (interrupts' deadline, which then ends the process): the
    partial folders being built, the temporary files noted in our locks, and the locks. A folder
    written in place keeps what its record lists, as after a kill."""
    for tmp in list(_building):
        remove_tree_quietly(tmp)
    lock.abandon()


interrupts.at_hard_stop(_abandon)
