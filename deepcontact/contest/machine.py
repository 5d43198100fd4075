"""What this machine lends a contestant's fence (bubblewrap's namespaces, control groups it may
write, libseccomp), tried once, and how a report says it: `fences()` names each fence and
whether it holds here; nothing missing is dropped silently."""
import ctypes
import errno
import os
import shutil
import subprocess
from functools import lru_cache

from . import kernel

# System calls a contestant never needs and a hostile one would use to cross its fence.
DENIED_CALLS = ("ptrace", "process_vm_readv", "process_vm_writev", "kcmp", "pidfd_getfd", "perf_event_open",
                "bpf", "userfaultfd", "keyctl", "add_key", "request_key", "mount", "umount2", "pivot_root",
                "move_mount", "open_tree", "fsopen", "fsmount", "fspick", "mount_setattr", "unshare", "setns", "open_by_handle_at",
                "name_to_handle_at", "kexec_load", "kexec_file_load", "init_module", "finit_module",
                "delete_module", "reboot", "swapon", "swapoff", "syslog", "acct", "quotactl", "settimeofday",
                "clock_settime", "clock_adjtime", "adjtimex", "iopl", "ioperm", "lookup_dcookie",
                "io_uring_setup", "io_uring_enter", "io_uring_register")
AF_UNIX = 1   # socket(AF_UNIX, ...) is refused every sandbox: see seccomp_program
SCMP_CMP_MASKED_EQ = 7   # libseccomp's (argument & datum_a) == datum_b

# What of a sandbox's own /proc is the machine's, not its namespace's: covered read-only. (bubblewrap
# covers these only where it may write them, and /proc/sys is a folder no one may write: where dc
# runs as root, a sandbox's user is the machine's root, who may write every setting in it. The
# machine's own are bound, read-only: bubblewrap binds from outside the new root)
PROC_READ_ONLY = ("sys", "sysrq-trigger", "irq", "bus")


def proc_read_only():
    """bubblewrap's options that cover PROC_READ_ONLY, after its --proc."""
    return [a for name in PROC_READ_ONLY if os.path.exists(f"/proc/{name}")
            for a in ("--ro-bind", f"/proc/{name}", f"/proc/{name}")]


@lru_cache(maxsize=None)
def bwrap():
    """The bubblewrap binary, if it can build a sandbox here (tried once, with every sandbox's
    /proc: user namespaces may be off, a mount under /proc/sys may refuse its bind), else None."""
    path = shutil.which("bwrap")
    if path is None:
        return None
    try:
        done = subprocess.run([path, "--unshare-all", "--unshare-user", "--die-with-parent", "--cap-drop", "ALL",
                               "--ro-bind", "/", "/", "--proc", "/proc", *proc_read_only(), "true"],
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return path if done.returncode == 0 else None


def _mounts():
    """[(mount point, fstype, super options)] of this process's mounts."""
    out = []
    try:
        with open("/proc/self/mountinfo") as f:
            for line in f:
                left, _, right = line.partition(" - ")
                fields, tail = left.split(), right.split()
                if len(fields) > 4 and len(tail) >= 3:
                    out.append((fields[4], tail[0], tail[2]))
    except OSError:
        pass
    return out


def _own_cgroups():
    """{hierarchy: path} of this process's control groups ("" for cgroup v2, else the v1 controller)."""
    out = {}
    try:
        with open("/proc/self/cgroup") as f:
            for line in f:
                _, controllers, path = line.rstrip("\n").split(":", 2)
                for c in (controllers.split(",") if controllers else [""]):
                    out[c] = path
    except OSError:
        pass
    return out


def _writable_dir(path):
    """Whether this process can make a folder in path."""
    probe = os.path.join(path, f"dc-probe-{os.getpid()}")
    try:
        os.mkdir(probe)
    except OSError:
        return False
    try:
        os.rmdir(probe)
    except OSError:
        pass
    return True


@lru_cache(maxsize=None)
def cgroup_roots():
    """Where the judge may make contestants' control groups: {"cpu": (kind, dir), "pids": ..., "memory": ...}
    (kind "v2" or "v1"), each a folder of the judge's own group it can write in."""
    own, found = _own_cgroups(), {}
    for point, fstype, options in _mounts():
        if fstype == "cgroup2" and "" in own:
            base = os.path.normpath(point + own[""])
            if not _writable_dir(base):
                continue
            found.setdefault("cpu", ("v2", base))   # (cpu.stat's usage is kept in every v2 group)
            try:
                with open(os.path.join(base, "cgroup.subtree_control")) as f:
                    enabled = f.read().split()
            except OSError:
                enabled = []
            for c in ("pids", "memory"):
                if c in enabled:
                    found.setdefault(c, ("v2", base))
        elif fstype == "cgroup":
            for c, wanted in (("cpuacct", "cpu"), ("pids", "pids"), ("memory", "memory")):
                if c in options.split(",") and c in own and wanted not in found:
                    base = os.path.normpath(point + own[c])
                    if _writable_dir(base):
                        found[wanted] = ("v1", base)
    return found


class _ArgRule(ctypes.Structure):
    """libseccomp's struct scmp_arg_cmp: argument `arg` compared (op) with datum_a."""
    _fields_ = [("arg", ctypes.c_uint), ("op", ctypes.c_int), ("datum_a", ctypes.c_uint64),
                ("datum_b", ctypes.c_uint64)]


# What each policy refuses beyond DENIED_CALLS and socket(AF_UNIX) (fence.Fence.seccomp names one).
# "contestant" and "job": a contestant or job forked from a zygote (forked.py) runs in a user
# namespace of its own, where making a namespace needs no capability, so clone may not ask for one
# (bubblewrap's --disable-userns does this for a fresh job), and clone3 (whose flags a filter
# cannot read) answers ENOSYS: the C library then falls back to clone.
# "contestant" also refuses sched_setaffinity: a contestant runs on the CPUs the judge's thread
# had (a fork is held to them before its filter is on; a fresh sandbox inherits them), which the
# measurement's protocol records and its charge bounds (charge.split_cpu); one that could widen
# them would make both untrue.
# "zygote": dc's own code only, which makes each fork's namespaces and mounts (a job's writable
# folders attached from the trees the judge made) before the fork's own filter is on.
SECCOMP_POLICIES = ("contestant", "job", "zygote")
ZYGOTE_ALLOWED = ("mount", "umount2", "unshare", "pivot_root", "move_mount", "mount_setattr")
CLONE_FLAGS = kernel.NAMESPACES


def _policy_rules(policy):
    """[(call, action, [argument rules])] of a policy (action: "refuse" (EPERM) or "absent" (ENOSYS))."""
    denied = [c for c in DENIED_CALLS if policy != "zygote" or c not in ZYGOTE_ALLOWED]
    rules = [(name, "refuse", []) for name in denied]
    # socket(AF_UNIX) refused to every profile; the kernel reads the family as a 32-bit int, so the
    # rule compares the low 32 bits (SCMP_CMP_MASKED_EQ): a family of 1 + 2**32 was let through
    rules.append(("socket", "refuse", [_ArgRule(0, SCMP_CMP_MASKED_EQ, 0xFFFFFFFF, AF_UNIX)]))
    if policy in ("contestant", "job"):   # (one rule a flag: any of them set refuses the call)
        rules += [("clone", "refuse", [_ArgRule(0, SCMP_CMP_MASKED_EQ, flag, flag)]) for flag in CLONE_FLAGS]
        rules.append(("clone3", "absent", []))
    if policy == "contestant":
        rules.append(("sched_setaffinity", "refuse", []))
    return rules


@lru_cache(maxsize=None)
def seccomp_program(policy="contestant"):
    """The seccomp filter of `policy` (SECCOMP_POLICIES), a BPF program's bytes from libseccomp,
    or None without libseccomp: DENIED_CALLS and socket(AF_UNIX) answered EPERM, and what
    _policy_rules adds. AF_UNIX: a read-only bind still lets a process connect to the sockets on
    it (a session bus, an agent, in a job's view of the whole file system) and ask a process
    outside the fence to act; socketpair() stays."""
    if policy not in SECCOMP_POLICIES:
        raise ValueError(f"no seccomp policy {policy!r}")
    try:
        lib = ctypes.CDLL("libseccomp.so.2", use_errno=True)
    except OSError:
        return None
    lib.seccomp_init.restype = ctypes.c_void_p
    lib.seccomp_init.argtypes = [ctypes.c_uint32]
    lib.seccomp_syscall_resolve_name.argtypes = [ctypes.c_char_p]
    lib.seccomp_rule_add_array.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int, ctypes.c_uint,
                                           ctypes.POINTER(_ArgRule)]
    lib.seccomp_export_bpf.argtypes = [ctypes.c_void_p, ctypes.c_int]
    lib.seccomp_release.argtypes = [ctypes.c_void_p]
    allow = 0x7FFF0000   # SCMP_ACT_ALLOW; SCMP_ACT_ERRNO(e) is 0x00050000 | e
    actions = {"refuse": 0x00050000 | errno.EPERM, "absent": 0x00050000 | errno.ENOSYS}
    ctx = lib.seccomp_init(allow)
    if not ctx:
        return None
    try:
        for name, action, args in _policy_rules(policy):
            number = lib.seccomp_syscall_resolve_name(name.encode())
            if number < 0:
                continue
            array = (_ArgRule * max(1, len(args)))(*args)
            if lib.seccomp_rule_add_array(ctx, actions[action], number, len(args), array) != 0:
                return None
        fd = os.memfd_create("dc-seccomp")
        try:
            if lib.seccomp_export_bpf(ctx, fd) != 0:
                return None
            os.lseek(fd, 0, os.SEEK_SET)
            return os.read(fd, 1 << 20)
        finally:
            os.close(fd)
    finally:
        lib.seccomp_release(ctx)


def fences():
    """{fence: True/False} of what this machine lends a contestant, for the report's protocol line."""
    namespaces, roots = bwrap() is not None, cgroup_roots()
    return {"namespaces": namespaces, "read-only view": namespaces,
            "seccomp": namespaces and seccomp_program() is not None,
            "cpu accounting": "cpu" in roots, "process limit": "pids" in roots,
            "memory limit": True, "file size limit": True}


def missing_fences():
    """The names of the fences this machine refuses (empty when every fence holds)."""
    return [name for name, held in fences().items() if not held]


def describe_fences():
    """One phrase for reports: the fences used, and any missing."""
    missing = missing_fences()
    roots = cgroup_roots()
    memory = "memory (control group)" if "memory" in roots else "memory (address space)"
    # (made by bubblewrap, or by a fork of the contestants' zygote itself: the same fence record)
    used = ("namespaces of its own (user, PID, mount, IPC, network, UTS), a read-only view, seccomp, "
            f"CPU charged from the control group, limits on processes, {memory} and file size")
    return used if not missing else f"{used}; MISSING here: {', '.join(missing)}"
