"""The Linux calls a fork of the zygote makes to fence itself (forked.py): namespaces, mounts,
pivot_root, capabilities, no new privileges, seccomp. Through libc, as bubblewrap makes them:
Python 3.11 has no os.unshare, mount or seccomp. Every call that fails raises OSError naming it."""
import ctypes
import os

CLONE_NEWNS = 0x00020000
CLONE_NEWCGROUP = 0x02000000
CLONE_NEWUTS = 0x04000000
CLONE_NEWIPC = 0x08000000
CLONE_NEWUSER = 0x10000000
CLONE_NEWPID = 0x20000000
CLONE_NEWNET = 0x40000000
# every namespace a contestant gets of its own (bubblewrap's --unshare-all and --unshare-user), and
# so what a contestant's clone may not ask for (machine.seccomp_program)
NAMESPACES = (CLONE_NEWUSER, CLONE_NEWNS, CLONE_NEWPID, CLONE_NEWNET, CLONE_NEWIPC, CLONE_NEWUTS, CLONE_NEWCGROUP)
ALL_NAMESPACES = sum(NAMESPACES)

MS_RDONLY, MS_NOSUID, MS_NODEV, MS_NOEXEC = 1, 2, 4, 8
MS_REMOUNT, MS_BIND, MS_REC, MS_PRIVATE = 32, 4096, 0x4000, 1 << 18
MNT_DETACH = 2

_PR_SET_PDEATHSIG = 1
_PR_SET_SECCOMP, _SECCOMP_MODE_FILTER = 22, 2
_PR_CAPBSET_DROP = 24
_PR_SET_NO_NEW_PRIVS = 38
_PR_CAP_AMBIENT, _PR_CAP_AMBIENT_CLEAR_ALL = 47, 4
_CAPABILITY_VERSION_3 = 0x20080522
_SYS_PIVOT_ROOT = 155   # (x86_64; glibc has no wrapper)
_SYS_OPEN_TREE, _SYS_MOVE_MOUNT = 428, 429   # (x86_64, Linux 5.2: glibc 2.36 has wrappers, Debian 12 has 2.36)
_AT_FDCWD, _OPEN_TREE_CLONE, _AT_RECURSIVE, _MOVE_MOUNT_F_EMPTY_PATH = -100, 1, 0x8000, 4
NAMESPACE_FLAGS = {"user": CLONE_NEWUSER, "mount": CLONE_NEWNS, "pid": CLONE_NEWPID, "net": CLONE_NEWNET,
                   "ipc": CLONE_NEWIPC, "uts": CLONE_NEWUTS, "cgroup": CLONE_NEWCGROUP}

_libc = ctypes.CDLL(None, use_errno=True)
_libc.mount.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_ulong, ctypes.c_char_p]
_libc.umount2.argtypes = [ctypes.c_char_p, ctypes.c_int]
_libc.prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]


def _checked(result, what):
    if result != 0:
        code = ctypes.get_errno()
        raise OSError(code, f"{what}: {os.strerror(code)}")


def _bytes(text):
    return None if text is None else os.fsencode(text)


def set_limits(file_size, memory=None, soft_only=False):
    """This process's limits: bytes of one file, no core file, bytes of address space (where
    memory is given); soft_only: no hard limit, so that a process it forks may set its own."""
    import resource
    hard = (lambda n: resource.RLIM_INFINITY) if soft_only else (lambda n: n)
    resource.setrlimit(resource.RLIMIT_FSIZE, (file_size, hard(file_size)))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    if memory is not None:
        resource.setrlimit(resource.RLIMIT_AS, (memory, hard(memory)))


def unshare(flags):
    """New namespaces (CLONE_* flags) for this process (a thread-less one: a user namespace needs it)."""
    _checked(_libc.unshare(ctypes.c_int(flags)), "unshare")


def map_user(uid, gid, inside=None):
    """In a new user namespace: this process's user and group (uid, gid, as they were outside)
    mapped to themselves, or to the (user, group) `inside` (one id each; setgroups refused, as the
    kernel asks of an unprivileged map)."""
    inner_uid, inner_gid = inside or (uid, gid)
    for name, text in (("setgroups", "deny"), ("uid_map", f"{inner_uid} {uid} 1"), ("gid_map", f"{inner_gid} {gid} 1")):
        with open(f"/proc/self/{name}", "w") as f:
            f.write(text)


def mount(source, target, fstype=None, flags=0, data=None):
    _checked(_libc.mount(_bytes(source), _bytes(target), _bytes(fstype), flags, _bytes(data)), f"mount {target}")


def bind(source, target, read_only=True, recursive=True):
    """source bound on target (made first: a folder or an empty file), read-only unless asked."""
    flags = MS_BIND | (MS_REC if recursive else 0)
    mount(source, target, None, flags)
    if read_only:
        mount(None, target, None, flags | MS_REMOUNT | MS_RDONLY | MS_NOSUID | MS_NODEV)


def namespace_flags(names):
    """The CLONE_* flags of a fence record's namespaces ("user", "mount", ...)."""
    return sum(NAMESPACE_FLAGS[name] for name in set(names))


def detached_trees(paths):
    """A detached copy of the mounts at each folder of `paths` (open_tree's clone, recursive, as
    bubblewrap's --bind), one descriptor each, for a fork of a zygote to attach writable in its
    own view (attach_tree): the zygote sees the file system read-only, so no fork of it can bind
    a folder writable from its own view. Made by a short-lived fork of this process in a user and
    mount namespace of its own, where cloning a mount needs no privilege (the kernel lets a
    detached tree be attached in another namespace: Linux 5.2). OSError where it cannot be."""
    import socket
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    uid, gid = os.getuid(), os.getgid()
    pid = os.fork()
    if pid == 0:   # (one thread here, as a user namespace needs; nothing of the parent's is touched)
        fds = []
        try:
            ours.close()
            unshare(CLONE_NEWUSER | CLONE_NEWNS)
            map_user(uid, gid)
            for path in paths:
                fd = _libc.syscall(_SYS_OPEN_TREE, _AT_FDCWD, _bytes(path),
                                   _OPEN_TREE_CLONE | _AT_RECURSIVE | os.O_CLOEXEC)
                if fd < 0:
                    _checked(-1, f"open_tree {path}")
                fds.append(fd)
            socket.send_fds(theirs, [b"T"], fds)
        except BaseException as e:
            try:
                theirs.send(b"E" + f"{e}".encode(errors="replace")[:500])
            except BaseException:
                pass
        os._exit(0)
    theirs.close()
    try:
        said, fds, _, _ = socket.recv_fds(ours, 1024, max(1, len(paths)))
    finally:
        ours.close()
        os.waitpid(pid, 0)
    if said != b"T" or len(fds) != len(paths):
        for fd in fds:
            os.close(fd)
        raise OSError(f"no detached tree of the folders ({said[1:].decode(errors='replace') or 'no answer'})")
    return fds


def attach_tree(fd, target):
    """The detached tree `fd` (detached_trees) attached at target, in this mount namespace."""
    _checked(_libc.syscall(_SYS_MOVE_MOUNT, fd, b"", _AT_FDCWD, _bytes(target), _MOVE_MOUNT_F_EMPTY_PATH),
             f"move_mount {target}")


class _MountAttr(ctypes.Structure):
    _fields_ = [("attr_set", ctypes.c_uint64), ("attr_clr", ctypes.c_uint64), ("propagation", ctypes.c_uint64),
                ("userns_fd", ctypes.c_uint64)]


_SYS_MOUNT_SETATTR, _MOUNT_ATTR_NOSUID, _MOUNT_ATTR_NODEV = 442, 0x2, 0x4


def restrict(target):
    """Every mount at and under target made nosuid and nodev, its other flags kept (bubblewrap's
    --bind does so to each mount it binds; mount_setattr, Linux 5.12)."""
    attr = _MountAttr(_MOUNT_ATTR_NOSUID | _MOUNT_ATTR_NODEV, 0, 0, 0)
    _checked(_libc.syscall(_SYS_MOUNT_SETATTR, _AT_FDCWD, _bytes(target), _AT_RECURSIVE, ctypes.byref(attr),
                           ctypes.sizeof(attr)), f"mount_setattr {target}")


def pivot_root(new_root, put_old):
    _checked(_libc.syscall(_SYS_PIVOT_ROOT, _bytes(new_root), _bytes(put_old)), "pivot_root")


def umount(target, flags=MNT_DETACH):
    _checked(_libc.umount2(_bytes(target), flags), f"umount {target}")


_SIOCGIFFLAGS, _SIOCSIFFLAGS, _IFF_UP = 0x8913, 0x8914, 0x1


def loopback_up():
    """The network namespace's loopback device up (bubblewrap's --unshare-net does so: a
    contestant's own 127.0.0.1, and nothing beyond it)."""
    import fcntl
    import socket
    import struct
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        flags = struct.unpack_from("H", fcntl.ioctl(s, _SIOCGIFFLAGS, struct.pack("16s24x", b"lo")), 16)[0]
        fcntl.ioctl(s, _SIOCSIFFLAGS, struct.pack("16sH22x", b"lo", flags | _IFF_UP))


def die_with_parent(signal_number):
    """This process sent signal_number when the thread that forked it ends."""
    _checked(_libc.prctl(_PR_SET_PDEATHSIG, signal_number, 0, 0, 0), "prctl(PDEATHSIG)")


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [("effective", ctypes.c_uint32), ("permitted", ctypes.c_uint32), ("inheritable", ctypes.c_uint32)]


def drop_capabilities():
    """Every capability gone: the bounding set, the ambient set, then the effective, permitted
    and inheritable ones (bubblewrap's --cap-drop ALL)."""
    for cap in range(64):
        if _libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            if ctypes.get_errno() == 22:   # (EINVAL: past the kernel's last capability)
                break
            _checked(-1, f"prctl(CAPBSET_DROP {cap})")
    _checked(_libc.prctl(_PR_CAP_AMBIENT, _PR_CAP_AMBIENT_CLEAR_ALL, 0, 0, 0), "prctl(CAP_AMBIENT_CLEAR_ALL)")
    header, data = _CapHeader(_CAPABILITY_VERSION_3, 0), (_CapData * 2)()
    _checked(_libc.capset(ctypes.byref(header), data), "capset")


class _SockFprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_void_p)]


def install_seccomp(program):
    """No new privileges, then the seccomp filter `program` (a BPF program's bytes, 8 a rule)."""
    _checked(_libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0), "prctl(NO_NEW_PRIVS)")
    if len(program) % 8 or not program:
        raise OSError(22, "seccomp: the program is not whole BPF rules")
    rules = ctypes.create_string_buffer(bytes(program), len(program))
    fprog = _SockFprog(len(program) // 8, ctypes.cast(rules, ctypes.c_void_p))
    _checked(_libc.prctl(_PR_SET_SECCOMP, _SECCOMP_MODE_FILTER, ctypes.addressof(fprog), 0, 0), "prctl(SECCOMP)")
