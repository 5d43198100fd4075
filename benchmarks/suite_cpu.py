"""Where the test suite's CPU goes: `make test`'s run (or the pytest arguments given after --),
each test charged the CPU of everything its worker ran meanwhile, its own process and every
process under it (the `dc` commands it started, their sandboxes and zygotes' forks), read from the
worker's own control group; then the tests and files that cost most, the tests that waited longest
(wall time their CPU did not fill: a deadline or a sleep waited out, a core left idle), and the
machine's time over the run (busy, idle, stolen by the host).

pytest's --durations gives wall time, which a loaded machine stretches and a test that waits
inflates; CPU is what `-n 2` on 2 cores divides, so the suite's wall time is about its CPU over 2
where both cores stay busy. Each xdist worker moves itself into a cgroup v1 cpuacct group of its
own (a child of its group, where writable: root or a delegated group), whose usage counts its
descendants'. Elsewhere (cgroup v2 too, where a worker moved into a group of its own would leave
the sandboxes' pids and memory controllers behind), a test is charged its worker's own CPU and
that of the processes it waited for (getrusage), which misses a sandbox's forks: said after the
run. A test that leaves a process running keeps its worker's group: named after the run.

--processes: also the run's CPU by kind of process, from the kernel's process accounting (acct(2):
root, and a kernel built with it; every process that ends is written, its CPU, parent and whether
it ran a new program), of pytest's process and its descendants (a process whose parent ended
before it is not found: its parent is then another): the test workers themselves; forks that ran
no new program (a zygote's contestants and jobs, a plug-in's or pytest's forks, a shell's
subshells); interpreters started afresh (python, dc: pytest itself, the tests' `dc` processes,
zygotes, pip); everything else (bubblewrap, chromium, ffmpeg, make). The machine has one
accounting file: a second `--processes` run at the same time is refused (a lock), and accounting
the machine had on (psacct's, say) is turned off by the run.

Usage: python benchmarks/suite_cpu.py [--top 25] [--out FILE.jsonl] [--processes] [-- PYTEST ARGS]
       (default pytest arguments: -q -m "not slow and not packaging" -n 2, as `make test`)
"""
import fcntl
import json
import os
import signal
import subprocess
import sys
import tempfile
import time

import pytest

WORKER_GROUP = "dc-suite-cpu"
ACCOUNTING_LOCK = os.path.join(tempfile.gettempdir(), "dc-process-accounting.lock")


# --- the pytest plug-in (loaded in each worker with -p suite_cpu) -------------------------------

_record = {}


def _move_into_own_group():
    """A usage reader of a new control group this process moved into, or None."""
    from deepcontact.contest import machine
    found = machine.cgroup_roots().get("cpu")
    if not found:
        return None
    kind, base = found
    if kind != "v1":
        return None
    try:
        folder = tempfile.mkdtemp(prefix=f"{WORKER_GROUP}-{os.getpid()}-", dir=base)   # (a name never taken)
        with open(os.path.join(folder, "cgroup.procs"), "w") as f:
            f.write(str(os.getpid()))
    except OSError:
        return None
    machine.cgroup_roots.cache_clear()   # (the sandboxes' cpuacct groups go under the worker's own now)
    path = os.path.join(folder, "cpuacct.usage")

    def usage():
        with open(path) as f:
            return int(f.read()) * 1e-9
    return usage


def _rusage():
    import resource
    return sum(getattr(resource.getrusage(who), f) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
               for f in ("ru_utime", "ru_stime"))


def pytest_configure(config):
    out = os.environ.get("DC_SUITE_CPU_OUT")
    if not out or (getattr(config.option, "numprocesses", None) and not hasattr(config, "workerinput")):
        return   # (xdist's controller runs no test)
    usage = _move_into_own_group()
    _record["usage"] = usage or _rusage
    _record["how"] = "control group" if usage else "getrusage"
    _record["file"] = open(f"{out}.{os.getpid()}", "a")   # (made now: a worker that runs no test is found too)
    _record["pid"] = os.getpid()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if "usage" not in _record:
        yield
        return
    wall, cpu = time.monotonic(), _record["usage"]()
    yield
    _record["file"].write(json.dumps({"test": item.nodeid, "cpu": _record["usage"]() - cpu, "wall": time.monotonic() - wall,
                                      "how": _record["how"], "worker": _record["pid"]}) + "\n")
    _record["file"].flush()


def _remove_worker_groups(workers):
    """The groups of the workers (pids) of this run, with the groups under them that a `dc` killed
    in a test left (dc's next sandbox would have swept them from the group it started in), each
    removed as dc removes a sandbox's, a process still in it (a worker of a stopped run, or a
    process a test left running) ended first, and said."""
    from deepcontact.contest import machine, sandbox
    found = machine.cgroup_roots().get("cpu")
    if not found or found[0] != "v1":
        return
    for name in os.listdir(found[1]):
        if not any(name.startswith(f"{WORKER_GROUP}-{pid}-") for pid in workers):
            continue
        for folder, _, _ in os.walk(os.path.join(found[1], name), topdown=False):
            left = _processes_in(folder)
            if left:
                print(f"ending {len(left)} process(es) the run left in {folder}: {', '.join(map(str, sorted(left)))}",
                      file=sys.stderr)
            sandbox._remove_groups({"cpu": ("v1", folder)})
            if os.path.exists(folder):
                print(f"the control group {folder} is left", file=sys.stderr)


def _processes_in(group):
    """The pids in a group."""
    try:
        with open(os.path.join(group, "cgroup.procs")) as f:
            return {int(line) for line in f if line.strip()}
    except OSError:
        return set()


# --- the script --------------------------------------------------------------------------------

def _machine_time():
    """(busy, idle, steal) seconds of all CPUs so far, from /proc/stat."""
    with open("/proc/stat") as f:
        fields = [int(v) for v in f.readline().split()[1:]]
    tick = os.sysconf("SC_CLK_TCK")
    user, nice, system, idle, iowait, irq, softirq, steal = fields[:8]
    return (user + nice + system + irq + softirq) / tick, (idle + iowait) / tick, steal / tick


def _accounting(path):
    """Starts the kernel's process accounting into path (None: stops it); an OSError where refused."""
    import ctypes
    libc = ctypes.CDLL(None, use_errno=True)
    if path is not None:
        open(path, "ab").close()   # (acct appends to a file that exists)
    if libc.acct(None if path is None else os.fsencode(path)) != 0:
        raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))


def _comp(v):   # (comp_t: a 13-bit mantissa and a 3-bit base-8 exponent, in AHZ ticks)
    return (v & 0x1FFF) << (3 * ((v >> 13) & 7))


def _accounted(path):
    """[(pid, ppid, forked without exec, command, CPU seconds)] of an acct_v3 file (linux/acct.h)."""
    import struct
    rows, data = [], open(path, "rb").read()
    for at in range(0, len(data) - 63, 64):
        flag, version, _, _, _, _, pid, ppid = struct.unpack_from("<BBHIIIII", data, at)
        utime, stime = struct.unpack_from("<HH", data, at + 32)
        if version != 3:
            continue
        comm = data[at + 48:at + 64].split(b"\0")[0].decode(errors="replace")
        rows.append((pid, ppid, bool(flag & 0x01), comm, (_comp(utime) + _comp(stime)) / 100))
    return rows


def _descendants(rows, root):
    """The rows of root's process and its descendants, by the parents the records name."""
    parent = {pid: ppid for pid, ppid, *_ in rows}
    mine = {}

    def of_root(pid):
        seen = []
        while pid not in mine and pid != root and pid in parent and pid > 1 and len(seen) < 10000:
            seen.append(pid)
            pid = parent[pid]
        verdict = mine.get(pid, pid == root)
        for p in seen:
            mine[p] = verdict
        return verdict
    return [r for r in rows if r[0] == root or of_root(r[0])]


def _by_kind(rows, workers):
    kinds = {}
    for pid, ppid, forked, comm, cpu in rows:
        if pid in workers:
            kind = "the test workers themselves"
        elif forked:
            kind = "forks that ran no new program (contestants, jobs, subshells, ...)"
        elif comm in ("python3", "python", "dc") or comm.startswith("python"):
            kind = "interpreters started afresh (dc, zygotes, pip, ...)"
        else:
            kind = "other programs (bubblewrap, chromium, ffmpeg, make, ...)"
        n, total = kinds.get(kind, (0, 0.0))
        kinds[kind] = (n + 1, total + cpu)
    print(f"\n{'CPU s':>8} {'processes':>10}  kind (process accounting)")
    for kind, (n, total) in sorted(kinds.items(), key=lambda kv: -kv[1][1]):
        print(f"{total:8.1f} {n:10d}  {kind}")


def _tables(rows, top):
    by_file = {}
    for r in rows:
        f = by_file.setdefault(r["test"].split("::")[0], [0, 0.0, 0.0])
        f[0] += 1
        f[1] += r["cpu"]
        f[2] += r["wall"]
    print(f"\n{'CPU s':>8} {'wall s':>8} {'tests':>6}  file (the {top} dearest)")
    for name, (n, cpu, wall) in sorted(by_file.items(), key=lambda kv: -kv[1][1])[:top]:
        print(f"{cpu:8.1f} {wall:8.1f} {n:6d}  {name}")
    print(f"\n{'CPU s':>8} {'wall s':>8}  test (the {top} dearest)")
    for r in sorted(rows, key=lambda r: -r["cpu"])[:top]:
        print(f"{r['cpu']:8.2f} {r['wall']:8.2f}  {r['test']}")
    # (a test's wall time its CPU does not fill: a deadline or a sleep waited out, a process waited
    # for; with two workers, what leaves a core idle)
    waits = sorted(rows, key=lambda r: r["cpu"] - r["wall"])[:top]
    print(f"\n{'wait s':>8} {'wall s':>8}  test (the {top} that waited longest: wall less CPU; "
          f"{sum(max(r['wall'] - r['cpu'], 0.0) for r in rows):.0f} s in all)")
    for r in waits:
        print(f"{r['wall'] - r['cpu']:8.2f} {r['wall']:8.2f}  {r['test']}")


def main():
    import argparse
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--top", type=int, default=25, help="how many tests and files to list (default 25)")
    ap.add_argument("--out", help="every test's row, as JSON lines, into this file")
    ap.add_argument("--processes", action="store_true", help="the CPU by kind of process (process accounting)")
    ap.add_argument("pytest_args", nargs="*", help="after --: pytest's arguments")
    args = ap.parse_args()
    if args.top < 1:
        ap.error(f"--top must be at least 1, got {args.top}")
    if args.out:
        try:
            open(args.out, "a").close()
        except OSError as e:
            ap.error(f"--out {args.out}: {e.strerror}")
    extra = args.pytest_args or ["-q", "-m", "not slow and not packaging", "-n", "2"]
    from deepcontact.protocol import current, protocol_line
    print(protocol_line(current()))
    # (a stop signal ends the run through the same clean-up as its end: accounting off, groups removed)
    def stop(signum, frame):
        raise SystemExit(128 + signum)
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGHUP, stop)
    with tempfile.TemporaryDirectory(prefix="dc-suite-cpu-") as folder:
        return _run(folder, extra, args)


def _rows(folder):
    return [json.loads(line) for name in sorted(os.listdir(folder))
            if name.startswith("tests.") for line in open(os.path.join(folder, name)) if line.endswith("\n")]


def _workers(folder):
    """The pids of the workers (each makes its rows' file, tests.PID, as it starts)."""
    return {int(name.split(".")[1]) for name in os.listdir(folder) if name.startswith("tests.")}


def _run(folder, extra, args):
    """pytest run with the plug-in, its rows written in folder; the tables printed; pytest's exit status."""
    stem = os.path.join(folder, "tests")
    env = dict(os.environ, DC_SUITE_CPU_OUT=stem,
               PYTHONPATH=os.pathsep.join(p for p in (os.path.dirname(os.path.abspath(__file__)),
                                                      os.environ.get("PYTHONPATH")) if p))
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    accounted = os.path.join(folder, "acct") if args.processes else None
    if accounted:
        try:
            lock = open(ACCOUNTING_LOCK, "a")
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            print(f"--processes: another run holds the machine's process accounting ({ACCOUNTING_LOCK}: {e.strerror})",
                  file=sys.stderr)
            return 1
        try:
            _accounting(accounted)
        except OSError as e:
            print(f"--processes: the kernel's process accounting is refused here ({e.strerror})", file=sys.stderr)
            return 1
    busy0, idle0, steal0 = _machine_time()
    wall0 = time.monotonic()
    pytest_run = None
    try:
        pytest_run = subprocess.Popen([sys.executable, "-m", "pytest", "-p", "suite_cpu", *extra], cwd=root, env=env)
        rc = pytest_run.wait()
    finally:
        if pytest_run is not None and pytest_run.poll() is None:   # (stopped: pytest is stopped too, then waited for)
            pytest_run.terminate()
            try:
                pytest_run.wait(30)
            except subprocess.TimeoutExpired:
                pytest_run.kill()
                pytest_run.wait()
        if accounted:
            _accounting(None)
        _remove_worker_groups(_workers(folder))
    wall = time.monotonic() - wall0
    busy1, idle1, steal1 = _machine_time()
    rows = _rows(folder)
    if args.out:
        with open(args.out, "w") as f:
            f.writelines(json.dumps(r) + "\n" for r in rows)
    how = sorted({r["how"] for r in rows})
    print(f"\npytest exit {rc}; {len(rows)} tests in {wall:.0f} s; the tests' CPU {sum(r['cpu'] for r in rows):.0f} s "
          f"({', '.join(how) or 'none recorded'}); the machine over the run: busy {busy1 - busy0:.0f} s, idle "
          f"{idle1 - idle0:.0f} s, stolen {steal1 - steal0:.0f} s of its {os.cpu_count()} CPUs")
    if "getrusage" in how:
        print("(no control group to write in: a test's CPU is its worker's and the processes it waited for; "
              "the sandboxes' forks are not counted)")
    if accounted:
        _by_kind(_descendants(_accounted(accounted), pytest_run.pid), _workers(folder))
    _tables(rows, args.top)
    return rc


if __name__ == "__main__":
    sys.exit(main())
