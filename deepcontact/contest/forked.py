"""The zygote's side (zygote.py is the judge's): one interpreter in its own bubblewrap sandbox
(fence.ZYGOTE) that imports numpy and the contestant's side once and runs nothing else, then
forks a contestant for each request. No plug-in code ever runs in it.

A request is a fence record (the contestant's: fence.Fence, as a dict), the contestant's
environment, and its descriptors: its line to the judge, its output and error, a status pipe,
its seccomp program, and the `cgroup.procs` files of its control groups, opened by the judge.
Each fork, before any code of its own runs, fences itself as bubblewrap fences a contestant:

1. into its control groups (the kernel checks the judge who opened the files), so its charge
   starts at birth; its limits on; a session of its own;
2. new user, mount, PID, network, IPC, UTS and cgroup namespaces, and a fork that is PID 1 of
   its own (a session of the namespace's own; it reaps, and its end ends every process of the
   namespace; it takes no signal from inside); its loopback up, as bubblewrap's;
3. its own view, built from the record: a new root holding the system folders and the few files
   of /etc, the readable folders, all read-only; its own /dev (the harmless device nodes and a
   size-limited /dev/shm), its own /tmp of file_size bytes, its own /proc (read-only) showing
   only its processes; pivot_root, the old root detached;
4. every capability dropped, no new privileges, the contest's seccomp filter (which also
   refuses clone of namespace flags);
5. a last fork runs the guest (guest.py) on its line, its standard input empty.

The status pipe carries "J" once the fence is up, then "X" and the contestant's exit code
(128 + a signal, as bubblewrap reports one) from the fork outside the namespace; "E" and a line
ended by NUL where the fence could not be built.
"""
import json
import os
import signal
import socket
import struct
import sys

from . import fence as fences, kernel, machine

DEVICES = ("null", "zero", "full", "random", "urandom", "tty")   # (bubblewrap's --dev, less its devpts)
DEV_LINKS = {"fd": "/proc/self/fd", "stdin": "/proc/self/fd/0", "stdout": "/proc/self/fd/1",
             "stderr": "/proc/self/fd/2"}
REQUEST_MAX = 1 << 20   # bytes of one request
READY = b"R"            # what the zygote says once its libraries are loaded
FDS_MAX = 16            # descriptors of one request
# Where a fork's new root is built, on a tmpfs of its own: a folder of the zygote's own (its
# private /dev/shm), which no path a contestant reads lies under (grants: never /dev)
BASE = "/dev/shm"


# What the jobs' zygote loads once: libraries only, none of dc's commands, so that nothing a job's
# own environment sets is read at an import made before it (dc's modules read DC_* variables as
# they load). The torch one's too (a fresh training job's interpreter took 3-4 s of CPU importing
# them: torch about 2, its compiler, which an optimiser's first step imports, about 1.5).
JOB_LIBRARIES = ("numpy", "lxml.etree", "click", "deepcontact._box2d")
JOB_TORCH_LIBRARIES = ("torch", "torch.nn", "torch.optim", "torch._dynamo")


def main(fd, package, torch=False, job=False):
    """The zygote: imports the contestant's side, then forks a contestant for each request on
    the socket `fd` until the judge closes it. package: the judge's deepcontact folder, which
    the zygote's must be (else it ends, and contestants start fresh); torch: torch and the model's
    side imported too, for contestants that load a trained network (about 2 s of CPU, once here
    rather than in each of them; one thread, as the zygote's fence sets)."""
    import deepcontact
    if os.path.dirname(os.path.abspath(deepcontact.__file__)) != package:
        sys.stderr.write(f"dc: the zygote found deepcontact at {deepcontact.__file__}, not in {package}\n")
        os._exit(3)
    if job:
        import importlib
        for name in JOB_LIBRARIES + (JOB_TORCH_LIBRARIES if torch else ()):
            importlib.import_module(name)
        rest = sys.path[1:]   # (less the judge's folder put first, and -c's current folder)
        _JOB_START["path"] = rest[1:] if rest[:1] == [""] else rest
    else:
        import multiprocessing.connection  # noqa: F401  (the contestant's libraries, loaded once)

        import numpy  # noqa: F401

        from . import guest  # noqa: F401
        if torch:
            import deepcontact.model.inference  # noqa: F401
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)   # (its forks are reaped by the kernel)
    import gc
    import resource  # noqa: F401
    gc.freeze()   # (its objects out of every fork's collections: a collection touched each page, so copied it)
    line = socket.socket(fileno=fd)
    # (a job's zygote says where each module it loaded lies: a job whose own path finds another
    # copy of one, its folder or its PYTHONPATH, starts fresh: the fork's copy is the zygote's)
    origins = {name: module.__file__ for name, module in list(sys.modules.items())
               if "." not in name and getattr(module, "__file__", None)} if job else {}
    try:   # (ready: the judge counts a fork's fence deadline from here, not from its imports)
        line.send(READY + (json.dumps(origins).encode() if origins else b""))
    except OSError:
        return
    while True:
        try:
            data, fds, _, _ = socket.recv_fds(line, REQUEST_MAX, FDS_MAX)
        except OSError:
            return
        if not data:
            return
        try:
            pid = os.fork()
        except OSError as e:   # (at its process limit: this contestant is refused, the zygote serves on)
            if len(fds) > 3:
                _report(fds[3], b"E", _line(e) + b"\0")
            pid = None
        if pid == 0:
            line.close()
            _outside(json.loads(data), fds)
        for f in fds:
            os.close(f)


_JOB_START = {}   # (the jobs' zygote: its import path as the interpreter made it)


def _report(status, kind, text=b""):
    try:
        os.write(status, kind + text)
    except OSError:
        pass


def _outside(request, fds):
    """The fork in the zygote's namespaces: into the groups, the limits, new namespaces; then the
    namespace's PID 1, whose exit code it reports. Never returns."""
    trees = len(request.get("job", {}).get("trees", ()))
    channel, out, err, status, seccomp, *groups = fds[:len(fds) - trees]
    trees = list(zip(request["job"]["trees"], fds[len(fds) - trees:])) if trees else []
    try:
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        null = os.open(os.devnull, os.O_RDWR)   # (the zygote's streams are not a contestant's to hold)
        for std in (0, 1, 2):
            os.dup2(null, std)
        os.close(null)
        for g in groups:   # (first: every CPU second from here on is the contestant's)
            os.write(g, b"0")
            os.close(g)
        kernel.die_with_parent(signal.SIGKILL)
        if request.get("cpus"):
            try:   # (where the judge's own set cannot be had, the zygote's stands)
                os.sched_setaffinity(0, request["cpus"])
            except OSError:
                pass
        _limits(request)
        os.setsid()
        uid, gid = os.getuid(), os.getgid()
        kernel.unshare(kernel.namespace_flags(request["fence"]["namespaces"]) | kernel.CLONE_NEWUSER)
        # (a job: as the judge's own user, as bubblewrap runs a fresh job; the zygote's user is
        # 65534 in its namespace, since no user namespace may map its parent's root)
        kernel.map_user(uid, gid, request["job"]["user"] if "job" in request else None)
        pid = os.fork()
        if pid == 0:
            _init(request, channel, out, err, status, seccomp, trees)
        for f in (channel, out, err, seccomp, *(fd for _, fd in trees)):
            os.close(f)
        _, code = os.waitpid(pid, 0)
        code = os.waitstatus_to_exitcode(code)
        _report(status, b"X", struct.pack("i", 128 - code if code < 0 else code))
    except BaseException as e:
        _report(status, b"E", _line(e) + b"\0")
    os._exit(0)


def _line(e):
    return f"{type(e).__name__}: {e}".encode(errors="replace")[:1000].replace(b"\0", b" ")


def _limits(request):
    import resource
    # (no memory group here: the address space instead; else none, as a fresh sandbox's, whatever
    # the zygote's own soft limit)
    memory = request.get("memory")
    if memory and "job" in request:   # (beyond the jobs' zygote's libraries, mapped before it ran: as a
        memory += _address_space()     # memory group charges a fork only the pages it makes)
    kernel.set_limits(request["fence"]["limits"]["file_size"], memory or resource.RLIM_INFINITY)


def _address_space():
    """Bytes of this process's address space now (0 where /proc does not say)."""
    try:
        with open("/proc/self/status") as f:
            return next((int(line.split()[1]) << 10 for line in f if line.startswith("VmSize:")), 0)
    except (OSError, ValueError):
        return 0


def _init(request, channel, out, err, status, seccomp, trees=()):
    """PID 1 of the contestant's namespaces: its view, its capabilities and filter; then the
    contestant's process, whose end is its own. Never returns."""
    try:
        kernel.die_with_parent(signal.SIGKILL)
        # (the zygote's Python handles SIGINT; a namespace's PID 1 with a handler takes the signal
        # from inside, and a contestant ended itself as "exit status 0": bubblewrap's PID 1 takes none)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        # (a session and process group of the namespace's own, as bubblewrap's --new-session: in the
        # outer fork's, a contestant's kill(0, ...) reached that fork, outside its PID namespace)
        os.setsid()
        record = request["fence"]
        if record["view"] == "root":
            _root_view(record, trees)
        else:
            _view(record)
        kernel.loopback_up()
        program = os.read(seccomp, 1 << 20)
        os.close(seccomp)
        kernel.drop_capabilities()
        kernel.install_seccomp(program)
        _report(status, b"J")
        os.close(status)
        pid = os.fork()
        if pid == 0:
            if "job" in request:
                _job(request, channel, out, err)
            _contestant(request, channel, out, err)
    except BaseException as e:
        _report(status, b"E", _line(e) + b"\0")
        os._exit(1)
    for f in (channel, out, err):
        os.close(f)
    while True:   # (the reaper of the namespace's orphans, until the contestant ends)
        ended, code = os.waitpid(-1, 0)
        if ended == pid:
            code = os.waitstatus_to_exitcode(code)
            os._exit(128 - code if code < 0 else code)


def _view(record):
    """The contestant's file system, from its fence record, in the order bubblewrap builds it
    (fence.bwrap_argv): /proc, /dev, /tmp, the system folders, /etc's few files, the readable,
    writable and device binds (a plug-in's file under /tmp is bound into the private /tmp)."""
    kernel.mount(None, "/", None, kernel.MS_REC | kernel.MS_PRIVATE)
    kernel.mount("tmpfs", BASE, "tmpfs", kernel.MS_NOSUID | kernel.MS_NODEV, "size=1m,mode=0755")
    root = BASE
    os.mkdir(root + "/proc")
    kernel.mount("proc", root + "/proc", "proc",
                 kernel.MS_RDONLY | kernel.MS_NOSUID | kernel.MS_NODEV | kernel.MS_NOEXEC)
    _dev(root, record)
    os.mkdir(root + "/tmp", 0o1777)
    if record["tmp"]:
        kernel.mount("tmpfs", root + "/tmp", "tmpfs", kernel.MS_NOSUID | kernel.MS_NODEV,
                     f"size={record['limits']['file_size']},mode=1777")
    for path in fences.SYSTEM:
        if os.path.islink(path):
            os.symlink(os.readlink(path), root + path)
        elif os.path.exists(path):
            _bound(path, root)
    os.mkdir(root + "/etc")
    for name in fences.ETC:
        if os.path.exists(f"/etc/{name}"):
            _bound(f"/etc/{name}", root)
    for path in sorted(dict.fromkeys(record["readable"]), key=lambda p: p.count("/")):
        _bound(path, root)
    for path in record["writable"]:
        _bound(path, root, read_only=False)
    for path in record["devices"]:
        _bound(path, root, read_only=False)
    os.chdir(root)
    os.mkdir(".old")
    kernel.pivot_root(".", ".old")
    kernel.umount("/.old")
    os.rmdir("/.old")
    kernel.mount(None, "/", None, kernel.MS_REMOUNT | kernel.MS_RDONLY | kernel.MS_NOSUID | kernel.MS_NODEV)
    os.chdir(record["cwd"] or "/tmp")


def _root_view(record, trees):
    """A job's file system, from its fence record, as bubblewrap builds a job's (fence.bwrap_argv):
    the whole file system read-only (the zygote's view, itself read-only), its own /proc and
    /dev, a /dev/shm of its own, and its writable folders: the detached trees the judge made of
    them (kernel.detached_trees), attached where they lie. Then the new root made the root."""
    kernel.mount(None, "/", None, kernel.MS_REC | kernel.MS_PRIVATE)
    kernel.mount("tmpfs", BASE, "tmpfs", kernel.MS_NOSUID | kernel.MS_NODEV, "size=1m,mode=0755")
    root = BASE + "/root"
    os.mkdir(root)
    kernel.bind("/", root)
    kernel.mount("proc", root + "/proc", "proc", kernel.MS_NOSUID | kernel.MS_NODEV | kernel.MS_NOEXEC)
    for name in machine.PROC_READ_ONLY:   # (the machine's settings: read-only, as a fresh job's)
        if os.path.exists(f"{root}/proc/{name}"):
            kernel.bind(f"{root}/proc/{name}", f"{root}/proc/{name}")
    _dev(root, record, shm_size=None)
    for path, fd in trees:
        kernel.attach_tree(fd, root + path)
        kernel.restrict(root + path)   # (no set-user-ID, no device files: bubblewrap's --bind)
        os.close(fd)
    os.chdir(root)
    kernel.pivot_root(".", ".")   # (the old root stacked under the new, then detached: no folder for it)
    kernel.umount(".")
    os.chdir(record["cwd"] or "/")


def _bound(path, root, read_only=True):
    """path bound at the same path under root (its mount point made where it is missing)."""
    target = root + path
    if not os.path.lexists(target):
        os.makedirs(os.path.dirname(target), exist_ok=True)
        if os.path.isdir(path):
            os.mkdir(target)
        else:
            open(target, "w").close()
    kernel.bind(path, target, read_only=read_only)


def _dev(root, record, shm_size=""):
    """Its own /dev: a tmpfs with the harmless device nodes bound in, the usual links, and a
    /dev/shm of file_size bytes (none shared with another contestant; shm_size None: the
    kernel's default size, as bubblewrap's --tmpfs for a job's)."""
    dev = root + "/dev"
    if not os.path.isdir(dev):   # (a job's view has one: covered)
        os.mkdir(dev)
    kernel.mount("tmpfs", dev, "tmpfs", kernel.MS_NOSUID, "size=64k,mode=0755")
    for name in DEVICES:
        if os.path.exists(f"/dev/{name}"):
            open(f"{dev}/{name}", "w").close()
            kernel.bind(f"/dev/{name}", f"{dev}/{name}", read_only=False, recursive=False)
    for name, target in DEV_LINKS.items():
        os.symlink(target, f"{dev}/{name}")
    if shm_size is None:   # (a job's /dev: bubblewrap's --dev whole, its terminals and /dev/core too)
        os.mkdir(f"{dev}/pts")
        kernel.mount("devpts", f"{dev}/pts", "devpts", kernel.MS_NOSUID | kernel.MS_NOEXEC,
                     "newinstance,ptmxmode=0666,mode=620")
        os.symlink("pts/ptmx", f"{dev}/ptmx")
        os.symlink("/proc/kcore", f"{dev}/core")
    os.mkdir(f"{dev}/shm")
    size = f"size={record['limits']['file_size']}," if shm_size is not None else ""
    kernel.mount("tmpfs", f"{dev}/shm", "tmpfs", kernel.MS_NOSUID | kernel.MS_NODEV, f"{size}mode=1777")


def _own_streams(channel, out, err):
    """A fresh interpreter's SIGINT, standard input empty, output and error its own, and no
    descriptor of the zygote's but `channel` (>= 3)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    null = os.open("/dev/null", os.O_RDONLY)
    os.dup2(null, 0)
    os.dup2(out, 1)
    os.dup2(err, 2)
    os.closerange(3, channel)
    os.closerange(channel + 1, os.sysconf("SC_OPEN_MAX"))


def _contestant(request, channel, out, err):
    """The contestant's process: its streams, its environment, then the guest. Never returns."""
    try:
        _own_streams(channel, out, err)
        os.environ.clear()
        os.environ.update(request["env"])
        _fresh_state()
        from .guest import main as guest_main
        guest_main(["", str(channel)])
    except BaseException as e:
        try:
            os.write(2, _line(e) + b"\n")
        except OSError:
            pass
    os._exit(1)


def _job(request, channel, out, err):
    """A job's process: what follows the interpreter in its command line ("-m MODULE ARGS" or "-c
    CODE ARGS") run as a fresh interpreter runs it (_as_started), ended as that interpreter ends
    (its threads joined, its exit functions run). Never returns."""
    code = 1
    try:
        how, what = _as_started(request, channel, out, err)
        try:
            _run(how, what)
            code = 0
        except SystemExit as e:
            code = _exit_code(e.code)
        except KeyboardInterrupt:
            _flush()
            signal.signal(signal.SIGINT, signal.SIG_DFL)   # (as an interpreter ends on one: by the signal)
            os.kill(os.getpid(), signal.SIGINT)
        except BaseException:
            sys.excepthook(*sys.exc_info())
            code = 1
        import atexit
        import threading
        threading._shutdown()
        atexit._run_exitfuncs()
        _flush()
    except BaseException as e:
        try:
            os.write(2, _line(e) + b"\n")
        except OSError:
            pass
    os._exit(code)


def _as_started(request, channel, out, err):
    """This process made what a fresh interpreter started for the job would be: its streams, its
    descriptor at the number the judge gave it (as Popen's pass_fds keeps one), its environment,
    import path, argv and the state its libraries drew as they loaded; (how, what) of its argv."""
    _own_streams(channel, out, err)
    job = request["job"]
    if job["fd"] != channel:
        os.dup2(channel, job["fd"])
        os.close(channel)
    os.environ.clear()
    os.environ.update(request["env"])
    os.environ[fences.MARKER] = request["fence"]["profile"]
    how, what, *args = job["argv"]
    # (as the interpreter makes it: -m's folder or -c's "" first, unless safe_path, then
    # PYTHONPATH's and its own, each once, made absolute, as site does)
    given = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    first = [] if sys.flags.safe_path else [os.getcwd() if how == "-m" else ""]
    sys.path[:] = first + [p for p in dict.fromkeys(os.path.abspath(p) for p in given + _JOB_START["path"])
                           if p not in first]
    sys.argv = [how, *args]
    sys.orig_argv = [sys.executable, how, what, *args]
    import time
    time.tzset()   # (TZ, as the interpreter read it)
    _site_customized()
    _fresh_state()
    import tempfile
    tempfile.tempdir = None   # (its TMPDIR, not one an import in the zygote looked up)
    _torch_paths()
    return how, what


def _run(how, what):
    """`python -m what` or `python -c what`, in this process, as __main__."""
    if how == "-m":
        import runpy
        runpy.run_module(what, run_name="__main__", alter_sys=True)
        return
    import types
    main = types.ModuleType("__main__")
    sys.modules["__main__"] = main
    exec(compile(what, "<string>", "exec"), vars(main))


def _exit_code(code):
    """An exit status from SystemExit's code, as the interpreter makes it (a text: said, then 1)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code & 0xFF
    try:
        sys.stderr.write(f"{code}\n")
    except Exception:
        pass
    return 1


def _flush():
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except Exception:
            pass


def _site_customized():
    """sitecustomize and usercustomize run as a fresh interpreter's site runs them, where the job's
    import path finds one the zygote did not run (one on its PYTHONPATH: a coverage hook, say)."""
    import importlib.util
    import site
    for name, run in (("sitecustomize", site.execsitecustomize), ("usercustomize", site.execusercustomize)):
        if name == "usercustomize" and not site.ENABLE_USER_SITE:
            continue
        try:
            found = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            found = None
        ran = sys.modules.get(name)
        if found is not None and found.origin != getattr(ran, "__file__", None):
            sys.modules.pop(name, None)
            run()


def _torch_paths():
    """The two paths torch's compiler looked up as the zygote imported it, looked up again as a
    fresh interpreter would: its cache under TMPDIR (and the user's name), its debug folder under
    the current folder. (Only these hold the zygote's folders: tests/test_zygote.py looks.)"""
    package = sys.modules.get("torch._dynamo.package")
    if package is not None:
        given = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
        try:
            package.DynamoCache._path_prefix = os.path.join(package.cache_dir(), "dynamo")
        except OSError:   # (no folder to write in: a listing's; its own /dev/shm stays the cache's)
            pass
        if given is None:   # (the lookup sets it: a job that never compiles is not told)
            os.environ.pop("TORCHINDUCTOR_CACHE_DIR", None)
    config = sys.modules.get("torch._dynamo.config")
    if config is not None:
        config.debug_dir_root = config.default_debug_dir_root()


def _fresh_state():
    """What a fresh interpreter would not share with its siblings: its random seeds (Python's,
    numpy's, torch's), and the import system's view of folders that changed since the zygote looked."""
    import importlib
    import random

    import numpy as np
    random.seed()
    if "numpy.random" in sys.modules:   # (else seeded afresh where a contestant imports it)
        np.random.seed()
    if "torch" in sys.modules:   # (the torch zygote's forks: torch seeds itself afresh as it starts)
        sys.modules["torch"].default_generator.seed()
    process = sys.modules.get("multiprocessing.process")
    if process is not None:   # (a key and a starting folder of its own, as multiprocessing draws them as it loads)
        process.current_process().authkey = os.urandom(32)
        process.ORIGINAL_DIR = os.getcwd()
    importlib.invalidate_caches()
