"""Atomic output: write to a temporary name in the same folder, then rename.

An interrupted run leaves either the complete file or nothing. Whole output folders go through
`output_folder`: locked against a second command, replaced only when every entry is one the
command's own record says it wrote, swapped in when complete by a journalled replacement that a
signal cannot cut in two and that the next command finishes or undoes if the process was killed.

Names beside an output ``NAME`` (shortened with a hash when NAME is long, so that they fit in 255
bytes): ``.NAME.lock`` (the lock), ``.NAME.partial-*`` (the output being built), ``.NAME.old-*``
(the output being replaced, only while ``.NAME.swap``, the journal, names it). Inside an output
folder, ``.dc-output.json`` records the command and every entry it wrote; nothing is ever taken
for the command's own by its name alone.
"""
import hashlib
import json
import logging
import os
import re
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path

log = logging.getLogger(__name__)

RECORD = ".dc-output.json"
RECORD_MAX = 64 << 20   # bytes: a record lists every file (a 600-step, 1,000-seed run's is about 21 MB)
JOURNAL_MAX = 4096      # bytes: a journal names two folders
NAME_MAX = 255     # bytes in one file name (Linux, macOS)
_SPARE = 40        # room left for the longest suffix we add (".partial-PID-XXXXXXXX", ".PID.tmp")

# Folders written in place (training), by absolute path: every file written there is entered in
# the folder's record before its bytes, so even a killed run leaves a record of what it wrote.
_in_place = {}

# Locks this process holds, by the absolute path of their output: the file descriptor, and the
# temporary files noted in it (a killed run's are removed by the next command to take the lock).
_locks = {}

# Outputs swapped in during this process: an interruption that comes after is said as such.
completed = []

# Partial folders this process is building (folder): what a hard stop removes.
_building = set()

# Output folders being written (a partial folder, or a folder written in place), by absolute path:
# a descriptor of the folder itself, opened without following a link. Every file made under one
# is made from that descriptor, one folder at a time and no link followed: a folder swapped for a
# link during the run is never written through, whatever the link points at.
_roots = {}


def short_name(name):
    """name, or for one too long to take a suffix, its start and a hash of the whole (still unique)."""
    raw = name.encode("utf-8", "surrogateescape")
    if len(raw) <= NAME_MAX - _SPARE:
        return name
    head = raw[:NAME_MAX - _SPARE - 12].decode("utf-8", "ignore")
    return f"{head}~{hashlib.sha1(raw).hexdigest()[:10]}"


def beside(path, kind):
    """The path of our ``.NAME.KIND`` file or folder beside path."""
    path = Path(path)
    return path.parent / f".{short_name(path.name)}.{kind}"


# --- The names this module makes: a control file's claim is acted on only for these -------------
# A journal, a lock's list or a record is a claim, not an order: whatever it names is touched only
# if it is a name this module would have made for that output, of the right kind on disk.

def own_name(path, kind, name):
    """Whether name is one this module makes beside the output path: kind "partial" or "old" (a
    folder: ``.NAME.partial-PID-XXXX``), or "tmp" (a temporary file: ``.NAME.XXXX.tmp``)."""
    if not isinstance(name, str):
        return False
    stem = re.escape(f".{short_name(Path(path).name)}.")
    tail = r"[A-Za-z0-9_]+\.tmp" if kind == "tmp" else re.escape(kind) + r"-\d+-[A-Za-z0-9_]+"
    return re.fullmatch(stem + tail, name) is not None


def temporary_name(name):
    """A temporary file's name as write_bytes makes it inside a folder written in place."""
    return isinstance(name, str) and re.fullmatch(r"\.[^/\x00]+\.\d+(_\d+)?\.tmp", name) is not None


def _kind(p):
    """What is at p, links not followed: "file", "folder", "other" (link, FIFO, device) or None."""
    try:
        mode = os.lstat(p).st_mode
    except OSError:
        return None
    return "file" if stat.S_ISREG(mode) else "folder" if stat.S_ISDIR(mode) else "other"


def _our_folder(p, empty_ok=False, command=None):
    """p is a real folder (no link) that holds our record (of `command`, where given), or
    (empty_ok) holds nothing."""
    if _kind(p) != "folder":
        return False
    rec = read_record(p)
    if rec is not None:
        return command is None or rec["command"] == command
    try:
        return empty_ok and not os.listdir(p)
    except OSError:
        return False


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


def _remove_claimed(folder, name, ours, why):
    """A temporary file a control file claims a killed run left in folder: removed if `name` is
    one dc makes there (ours) and a regular file; anything else left alone, said in one line (why).
    A name that is not ours is never looked up (it may be a path elsewhere, or hold a NUL)."""
    p = folder / name if ours else None
    kind = _kind(p) if ours else None
    if not ours or kind not in ("file", None):
        log.warning("left %s alone: %s", p if ours else repr(name), why)
    elif kind == "file":
        log.info("removing %s, left by an interrupted earlier run", p)
        _remove_quietly(p)


def _abandon():
    """What unwinding would remove, removed from another thread while the main thread is stuck in
    a plug-in that swallowed the stop (interrupts' deadline, which then ends the process): the
    partial folders being built, the temporary files noted in our locks, and the locks. A folder
    written in place keeps what its record lists, as after a kill."""
    import shutil
    for tmp in list(_building):
        shutil.rmtree(tmp, ignore_errors=True)
    for key, (_, names) in list(_locks.items()):
        for name in names:
            _remove_quietly(Path(key).parent / name)
        _remove_quietly(beside(key, "lock"))


def make_folder_for(path):
    """Makes the folder an output goes in (and its parents), as every output does. A folder
    named before a '..' must be there already: `-o x/../y` made a folder x only to go up out of
    it. InputError naming path for either."""
    from .errors import InputError
    parts = Path(path).parent.parts
    for k, part in enumerate(parts):
        if part == ".." and k and not Path(*parts[:k]).is_dir():
            raise InputError(f"the folder {Path(*parts[:k])} before '..' does not exist: give the output's path "
                             f"without going into a folder that is not there", path)
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", path) from None


def _keep_attributes(folder, onto):
    """The user's folder's mode, group and extended attributes onto the folder that replaces it (a
    colleague's group, a setgid bit, an ACL or a label set on an empty output folder stay). What
    this user may not set is left as it is."""
    st = os.lstat(folder)
    os.chmod(onto, stat.S_IMODE(st.st_mode))
    try:
        os.chown(onto, -1, st.st_gid)
        os.chmod(onto, stat.S_IMODE(st.st_mode))   # (chown clears a setgid bit: set it again)
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


def umask():
    """This process's umask (read by setting it, and set back at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_replaceable(path, where=None, name=None):
    """Refuses (InputError) an output path that is there but is not a regular file: a folder, a
    device, a FIFO or a socket is never replaced by a file, and a symbolic link never followed.
    (where, name): path as _at gives it."""
    from .errors import InputError
    try:
        st = os.stat(path if name is None else name, dir_fd=where, follow_symlinks=False)
    except FileNotFoundError:
        return
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", path) from None
    if stat.S_ISLNK(st.st_mode):
        raise InputError("is a symbolic link: refusing to write through it or replace it", path)
    if not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a special file (device, FIFO or socket)"
        raise InputError(f"is {kind}, not a regular file: refusing to replace it", path)


def write_bytes(path, data: bytes):
    """data at path, atomically: complete or not there (an earlier file stays until replaced).
    Written to a new temporary file of ours (never one found there: a name planted there, a hard
    link to a user's file say, is never opened) and renamed over path."""
    # The hot path of `dc simulate` (one call per step): plain os calls, a temporary name
    # unique to this process (tempfile.mkstemp costs more than the write itself).
    path = os.fspath(path)
    with _at(path) as (where, name):
        check_replaceable(path, where, name)
        record = _in_place.get(os.path.dirname(os.path.abspath(path))) if _in_place else None

        def note(tmp):   # before its bytes: a killed run's temporary file is then known
            if _locks and os.path.abspath(path) in _locks:
                note_temporary(path, tmp)
            if record is not None:
                record.enter(name, tmp)
        fd = tmp = None
        try:
            # held: a stop between making the file and knowing its name would leave it behind
            with _interrupts.held():
                fd, tmp = _create_temporary(where, name, note)
        except OSError as e:
            raise type(e)(e.errno, e.strerror, path) from None
        except BaseException:
            if tmp is not None:
                os.close(fd)
                _remove_quietly(tmp, where)
            raise
        try:
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
            finally:
                os.close(fd)
            os.replace(tmp, name, src_dir_fd=where, dst_dir_fd=where)
        except OSError as e:
            _remove_quietly(tmp, where)
            # name the file asked for, not the temporary one
            raise type(e)(e.errno, e.strerror, path) from None
        except BaseException:
            _remove_quietly(tmp, where)
            raise


def _create_temporary(where, name, note=None, mode=0o666):
    """A new file of ours beside name (in the folder `where`, a descriptor or None): (fd, its
    name), made with O_EXCL, so a name that is taken (a leftover, or a hard link planted there) is
    never opened, let alone truncated; the next free name is taken instead. note(tmp) is called
    before each name is made. The mode is less the umask, as any file's."""
    import errno
    base = f".{short_name(name)}.{os.getpid()}"
    for k in range(1000):
        tmp = f"{base}.tmp" if k == 0 else f"{base}_{k}.tmp"
        if note is not None:
            note(tmp)
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode, dir_fd=where), tmp
        except FileExistsError:
            continue
    raise OSError(errno.EEXIST, "no free temporary name beside it", name)


@contextmanager
def _at(path):
    """(folder, name): where path is made, folder a descriptor of its folder. Under an output
    folder being written (_roots), that folder is opened from the output's own, no link followed.
    OSError naming path where a folder on the way is not a real
    folder (a link put there during the run)."""
    a = os.path.abspath(path)
    root = max((r for r in _roots if a.startswith(r + os.sep)), key=len, default=None) if _roots else None
    if root is None:   # (the user's own folder: its path is theirs to give)
        head, name = os.path.split(a)
        try:
            where = os.open(head, os.O_RDONLY | os.O_DIRECTORY)
        except OSError as e:
            raise OSError(e.errno, e.strerror, os.fspath(path)) from None
        try:
            yield where, name
        finally:
            os.close(where)
        return
    parts = a[len(root) + 1:].split(os.sep)
    where, opened = _roots[root], []
    try:
        for part in parts[:-1]:
            try:
                where = os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=where)
            except OSError as e:
                import errno
                if e.errno in (errno.ELOOP, errno.ENOTDIR):
                    raise OSError(e.errno, f"the folder {part} on the way is not the one dc made (a link, or a "
                                           f"file, was put in its place during the run): not written through",
                                  os.fspath(path)) from None
                raise OSError(e.errno, e.strerror, os.fspath(path)) from None
            opened.append(where)
        yield where, parts[-1]
    finally:
        for fd in opened:
            os.close(fd)


def _hold_root(folder):
    """Registers folder (just made by this run, or an in-place output checked as a real folder) as
    an output being written: what is made under it is made from its descriptor (_at). Returns the
    folder's identity."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    _roots[os.path.abspath(folder)] = fd
    st = os.fstat(fd)
    return [st.st_dev, st.st_ino]


def _release_root(folder):
    fd = _roots.pop(os.path.abspath(folder), None)
    if fd is not None:
        os.close(fd)


def make_dir(path):
    """A new folder at path (made from the output's descriptor when under one: _at)."""
    with _at(path) as (where, name):
        try:
            os.mkdir(name, dir_fd=where)
        except OSError as e:
            raise OSError(e.errno, e.strerror, os.fspath(path)) from None


def open_fd(path, flags, mode=0o666):
    """os.open(path, flags) with no link followed in its last name, and under an output folder
    being written, in none on the way (_at); an OSError names path."""
    with _at(path) as (where, name):
        try:
            return os.open(name, flags | os.O_NOFOLLOW, mode, dir_fd=where)
        except OSError as e:
            raise OSError(e.errno, e.strerror, os.fspath(path)) from None


def open_new(path, mode="wb"):
    """A new file at path, opened for writing (O_EXCL: nothing found there is opened; open_fd):
    for a file written piece by piece inside an output folder being built, whose swap makes it
    appear whole."""
    fd = open_fd(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL)
    return os.fdopen(fd, mode, **({"newline": ""} if "b" not in mode else {}))


def new_temporary(path):
    """A new temporary file of ours beside the output path (noted in path's lock, if held): its
    path, for a program that writes it (ffmpeg) before it is renamed over path."""
    note = (lambda tmp: note_temporary(path, tmp)) if _locks and os.path.abspath(path) in _locks else None
    with _at(path) as (where, name):
        fd, tmp = _create_temporary(where, name, note)
    os.close(fd)
    return Path(path).parent / tmp


def write_text(path, text: str):
    write_bytes(path, text.encode("utf-8"))


def figure_bytes(fig, fmt, **savefig):
    """A matplotlib figure as the bytes of a picture (written with write_bytes, never in place)."""
    import io
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, **savefig)
    return buf.getvalue()


@contextmanager
def open_for_write(path, mode="wb"):
    """A file object whose content appears at ``path`` only if the block completes."""
    path = os.fspath(path)
    with _at(path) as (where, name):
        check_replaceable(path, where, name)
        note = (lambda tmp: note_temporary(path, tmp)) if _locks and os.path.abspath(path) in _locks else None
        try:
            fd, tmp = _create_temporary(where, name, note)
        except OSError as e:
            raise type(e)(e.errno, e.strerror, path) from None
        try:
            with os.fdopen(fd, mode) as f:
                yield f
            os.replace(tmp, name, src_dir_fd=where, dst_dir_fd=where)
        except BaseException:
            _remove_quietly(tmp, where)
            raise


def _remove_quietly(path, where=None):
    try:
        os.unlink(path, dir_fd=where)
    except OSError:
        pass


# --- What an output folder holds: its record ----------------------------------------------------

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
        rec = json.loads(p.read_bytes())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    ok = (isinstance(rec, dict) and isinstance(rec.get("command"), str) and rec.get("state") in ("partial", "done")
          and all(isinstance(rec.get(k), list) and all(isinstance(x, str) for x in rec[k])
                  for k in ("files", "temporary")))
    return rec if ok else None


def _write_record(folder, command, state, files=(), temporary=()):
    write_text(Path(folder) / RECORD, json.dumps({"command": command, "state": state, "files": sorted(files),
                                                  "temporary": sorted(temporary)}, indent=0) + "\n")


class Owned:
    """What one kind of output is called (``what``) and, for the reader, what it holds
    (``patterns``); which entries are the command's own is decided by the record the command left
    inside the folder, never by these names."""

    def __init__(self, what, patterns=()):
        self.what = what
        self.patterns = list(patterns)


class _InPlace:
    """The record of a folder written in place, kept up to date as files are written."""

    def __init__(self, folder, command):
        self.folder, self.command = Path(folder), command
        rec = read_record(folder)
        mine = rec is not None and rec["command"] == command
        self.files = set(rec["files"]) if mine else set()
        # temporary files a killed run of ours left: ours to remove
        for name in (rec["temporary"] if mine else ()):
            _remove_claimed(self.folder, name, temporary_name(name),
                            f"the record {RECORD} lists it as a temporary file, but it is not one dc writes there")
        self.temporary = set()
        self.save()

    def enter(self, name, tmp):
        if name not in self.files or tmp not in self.temporary:
            self.files.add(name)
            self.temporary.add(tmp)
            self.save()

    def save(self, final=False):
        if final:   # what is there now, of what we wrote
            self.files = {f for f in self.files if (self.folder / f).exists()}
            self.temporary = {t for t in self.temporary if (self.folder / t).exists()}
        _write_record(self.folder, self.command, "done", self.files, self.temporary)


# --- Locks, leftovers and the replacement journal -----------------------------------------------

@contextmanager
def locked(path):
    """Holds an exclusive lock on ``.NAME.lock`` beside path, or refuses at once. The folder path
    goes in is made first, as for every output (`dc render -o figures/x.png`)."""
    import errno
    import fcntl
    from .errors import InputError
    lock = beside(path, "lock")
    make_folder_for(path)
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise InputError(f"the lock file {lock.name} beside it is a symbolic link: refusing to follow "
                                 "it; remove it", path) from None
            raise InputError(f"cannot write there: {e.strerror or e}", path) from None
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            os.close(fd)
            raise InputError(f"the lock file {lock.name} beside it is not a regular file; remove it", path)
        if st.st_nlink != 1:   # (a hard link to a user's file: truncating the lock would empty it)
            os.close(fd)
            raise InputError(f"the lock file {lock.name} beside it is a hard link to another file ({st.st_nlink} "
                             f"names): refusing to write to it; remove it", path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError("another dc command is writing this output now; wait for it or choose another "
                             "output", path) from None
        try:   # the holder before us may have removed the file: then lock the new one
            if os.stat(lock, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    # temporary files that the lock's last holder noted and did not live to remove: ours
    try:
        noted = json.loads(os.pread(fd, 1 << 16, 0) or b"[]")
    except (OSError, ValueError, UnicodeDecodeError):
        noted = []
    for name in noted if isinstance(noted, list) else ():
        _remove_claimed(Path(path).parent, name, own_name(path, "tmp", name),
                        f"the lock file {lock.name} lists it, but it is not a temporary file dc makes for "
                        f"{Path(path).name}")
    os.ftruncate(fd, 0)
    key = os.path.abspath(path)
    _locks[key] = (fd, [])
    try:
        yield
    finally:
        _locks.pop(key, None)
        _remove_quietly(lock)
        os.close(fd)


def note_temporary(path, tmp):
    """Enters tmp, a temporary file beside the output path, in path's lock (held by this
    process), so that if the process is killed the next command on path removes it."""
    entry = _locks.get(os.path.abspath(path))
    if entry is None:
        return
    fd, names = entry
    name = os.path.basename(os.fspath(tmp))
    if name not in names:
        names.append(name)
        data = json.dumps(names).encode()
        os.pwrite(fd, data, 0)
        os.ftruncate(fd, len(data))


def recover(path, command=None):
    """Finishes or undoes what a killed earlier command left beside path (called under its lock,
    so no running command owns any of it): a replacement cut between its renames is undone (the
    earlier output restored) or, when the new output is in place, finished; partial folders that
    hold our record (of `command`, where given) are removed. Nothing without our record or journal is
    touched, and a journal or record is a claim, checked, never an order (own_name, _read_journal)."""
    import shutil
    path = Path(path)
    journal = beside(path, "swap")
    claims = _read_journal(journal, path)
    if claims is not None:
        old, new = (path.parent / claims[k] for k in ("old", "new"))
        # each the very folder the journal named (by identity, not only by name and record: a
        # complete output of dc's moved under one of those names is not a swap's leftover)
        old_ours = _our_folder(old, empty_ok=True, command=command) and _is(old, claims.get("old_id"))
        new_ours = _our_folder(new, command=command) and _is(new, claims.get("new_id"))
        if not os.path.lexists(path) and old_ours:
            # killed between the renames: the earlier output is the only copy, and comes back
            os.replace(old, path)
            log.warning("restored %s from %s: an earlier replacement was interrupted before the new output "
                        "was in place", path, old.name)
        elif old_ours:
            # killed after the swap, while the earlier output was being removed
            log.info("removing %s, the output an interrupted replacement had already replaced", old)
            shutil.rmtree(old, ignore_errors=True)
        if new_ours:   # never swapped in: ours, unfinished
            log.info("removing %s, left by an interrupted earlier run", new)
            shutil.rmtree(new, ignore_errors=True)
        for p, ours in ((old, old_ours), (new, new_ours)):
            if not ours and os.path.lexists(p) and p != path:
                log.warning("left %s alone: the journal %s names it, but it is not the folder the journal "
                            "wrote of (no record of dc's, or another folder under that name)", p, journal.name)
        _remove_quietly(journal)
    for p in path.parent.iterdir() if path.parent.is_dir() else ():
        if own_name(path, "partial", p.name) and _our_folder(p, command=command):
            if read_record(p)["state"] == "partial":
                log.info("removing %s, left by an interrupted earlier run", p)
                shutil.rmtree(p, ignore_errors=True)


def _read_journal(journal, path):
    """The folders a journal beside path names, {"old": name, "new": name}, or None if there is no
    journal. One that is not a regular file, or does not name two folders of the kinds `folder`
    makes for path, is refused (InputError) and left as it is: nothing it names is touched."""
    import errno
    from .errors import InputError
    kind = _kind(journal)
    if kind is None:
        return None
    refuse = f"the journal {journal.name} beside it"
    if kind != "file":
        raise InputError(f"{refuse} is not a regular file (a link, folder, FIFO or device): nothing was done; "
                         f"remove it", path)
    try:
        fd = os.open(journal, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        try:
            data = os.read(fd, JOURNAL_MAX + 1) if stat.S_ISREG(os.fstat(fd).st_mode) else None
        finally:
            os.close(fd)
        claims = json.loads(data) if data is not None and len(data) <= JOURNAL_MAX else None
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


@contextmanager
def folder(path, command="dc"):
    """A temporary folder beside `path` that becomes `path` only if the block completes.

    The swap is journalled (``.NAME.swap`` names the earlier output while it is moved aside) and
    held against stop signals, which are raised once it is done; a process killed in the middle is
    finished or undone by `recover`. On failure, Ctrl-C or a signal before the swap the temporary
    folder is removed and `path` is left as it was."""
    import shutil
    from . import interrupts
    from .errors import InputError
    path = Path(path)
    tmp, swapped, built, old, before, journalled = None, False, None, None, None, False
    # the swap's own names must be free before any work, not found taken at its end (recover has
    # finished or refused whatever an earlier run left; anything there now, a link, a FIFO, a
    # folder, was put there since, or by a caller that did not recover)
    journal = beside(path, "swap")
    if os.path.lexists(journal):
        raise InputError(f"the journal {journal.name} beside it is there before this run began its work (a "
                         f"{_kind(journal) or 'file'}): nothing was done; remove it", path)
    try:
        # held: a stop signal between making the folder and owning it would leave it behind
        with interrupts.held():
            try:
                tmp = Path(tempfile.mkdtemp(prefix=f".{short_name(path.name)}.partial-{os.getpid()}-",
                                            dir=path.parent))
                _building.add(tmp)
                built = _hold_root(tmp)
                os.chmod(tmp, 0o777 & ~umask())   # the output's own mode: mkdtemp's 0700 is for secrets
                _write_record(tmp, command, "partial")
            except OSError as e:
                raise InputError(f"cannot write there: {e.strerror or e}", path) from None
        yield tmp
        if not _is(tmp, built):   # (what is there now is not what this run built: swap in nothing)
            raise InputError(f"the output being built, {tmp.name}, was moved or replaced during the run (by a link "
                             f"or another folder): nothing was swapped in, and {path.name} is as it was", path)
        with interrupts.held():
            # the journal first: from here on, a kill at any instruction is finished or undone by
            # the next command (recover), which finds the earlier output or the new one, whole
            old = tmp.with_name(tmp.name.replace(".partial-", ".old-", 1))   # (unique as tmp's name is)
            before = _identity(path) if os.path.lexists(path) else None
            write_text(beside(path, "swap"), json.dumps({
                "old": old.name, "new": tmp.name, "new_id": _identity(tmp), "old_id": before}) + "\n")
            journalled = True
            _write_record(tmp, command, "done", [r for r in entries(tmp) if r != RECORD])
            if os.path.lexists(path):
                _keep_attributes(path, tmp)
                os.replace(path, old)
            os.replace(tmp, path)
            swapped = True
            completed.append(path)
            if old.exists():
                shutil.rmtree(old, ignore_errors=True)
            _remove_quietly(beside(path, "swap"))
    except BaseException:
        if tmp is not None and not swapped:
            # (a full disk or a file system gone read-only in the swap: undone here as far as it
            # can be, so that nothing is left for the next run to finish or undo)
            try:
                if old is not None and os.path.lexists(old) and not os.path.lexists(path) and _is(old, before):
                    os.replace(old, path)
                if _is(tmp, built):
                    shutil.rmtree(tmp, ignore_errors=True)
                if journalled and not os.path.lexists(tmp) and not (old is not None and os.path.lexists(old)):
                    _remove_quietly(beside(path, "swap"))
            except OSError:   # (what is left, the journal names: the next run finishes or undoes it)
                pass
        raise
    finally:
        _building.discard(tmp)
        if tmp is not None:
            _release_root(tmp)


# --- Output folders ----------------------------------------------------------------------------
# A command's output folder is replaced (--overwrite) only if its record says that command wrote
# it and every entry in it is one the record lists. Two commands never write one output at once:
# each holds an exclusive lock on `.NAME.lock` beside it while it works.

@contextmanager
def output_folder(path, owned, overwrite=False, *, command, in_place=False, existing_ok=False,
                  hint="use --overwrite to replace it"):
    """The folder a command writes its output in, checked, locked and atomic.

    A new or empty ``path`` is written; an existing output only with overwrite, and only if its
    record says dc ``command`` wrote every entry in it (else the first foreign path is named).
    Normally the output is built in ``.NAME.partial-*`` beside path and swapped in when complete,
    so a failed or interrupted command leaves path as it was. in_place: write into path itself
    (training, which resumes from what it wrote), entering each file in the record before writing
    it; a folder it created is removed again if it holds nothing but the record. existing_ok: an
    existing output is written into (resuming) without overwrite. hint: what the message for an
    output that is there already suggests."""
    from . import interrupts
    from .errors import InputError, show_path
    path = Path(path)
    if path.is_symlink():
        raise InputError("is a symbolic link: refusing to write through it; give the folder itself", path)
    if os.path.lexists(path) and not path.is_dir():
        raise InputError("exists and is not a folder", path)
    if not in_place and path.is_dir() and os.path.ismount(path):
        # (swapped in by renaming it aside, which a mount point refuses: found at the end, after the work)
        raise InputError(f"is a mount point: an output is swapped in by renaming, which a mount point refuses; "
                         f"give a folder inside it (-o {show_path(path / 'out')})", path)
    here = Path.cwd().resolve()
    if path.resolve() == here or path.resolve() in here.parents:
        raise InputError("is the current folder or one above it: give the output a folder of its own "
                         "(e.g. -o out)", path)
    with locked(path):   # (which makes the folder the output goes in)
        recover(path, command)
        existing = path.is_dir() and any(path.iterdir())
        if existing and not existing_ok:
            check_owned_folder(path, command, overwrite, owned.what, hint)
        if not in_place:
            with folder(path, command) as tmp, _named(path, tmp):
                yield tmp
            return
        created = not path.exists()
        key = os.path.abspath(path)
        try:
            with interrupts.held():   # a stop between making the folder and owning it would leave it
                path.mkdir(exist_ok=True)
                _hold_root(path)
                _in_place[key] = record = _InPlace(path, command)
            with _named(path, path):
                yield path
        except BaseException:
            if created and path.is_dir() and set(os.listdir(path)) <= {RECORD}:
                _remove_quietly(path / RECORD)
                path.rmdir()
                _in_place.pop(key, None)
            raise
        finally:
            if _in_place.pop(key, None) is not None:
                record.save(final=True)
            _release_root(path)


def check_owned_folder(path, command, overwrite, what="folder", hint="use --overwrite to replace it"):
    """Refuses (InputError) to replace the non-empty folder at path unless overwrite is given, its
    record says dc `command` wrote it, completely, and it holds nothing else: --overwrite never
    deletes what the command did not write."""
    from .errors import InputError
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


def hold_building(folder, command):
    """A folder this process just made beside an output, held as a partial output of dc `command`:
    a hard stop removes it, and so does the next command on that output (recover) if this process
    is killed."""
    _building.add(Path(folder))
    _write_record(folder, command, "partial")


def release_building(folder):
    _building.discard(Path(folder))


@contextmanager
def _named(path, work):
    """An OSError names the file under its final name (not the partial folder's, which is gone),
    or the output itself when it names none (a plot, a full disk)."""
    try:
        yield
    except OSError as e:
        if e.errno is None:
            raise
        name = os.fspath(path) if e.filename is None else os.fspath(e.filename)
        if name.startswith(os.fspath(work)):
            name = os.fspath(path) + name[len(os.fspath(work)):]
        raise OSError(e.errno, e.strerror, name) from None


from . import interrupts as _interrupts   # (interrupts imports nothing of ours)
_interrupts.at_hard_stop(_abandon)
