"""benchmarks/suite_cpu.py charges each test the CPU of what it ran: its own and its processes'."""
import json
import os
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

SCRIPT = Path(__file__).parent.parent / "benchmarks" / "suite_cpu.py"

BURN = textwrap.dedent('''
    import subprocess
    import sys

    SPIN = "import time\\nwhile time.process_time() < 0.4: pass"

    def test_its_child_burns():
        subprocess.run([sys.executable, "-c", SPIN], check=True)

    def test_idle():
        pass
''')


def test_a_tests_child_processes_are_charged_to_it(tmp_path):
    (tmp_path / "test_burn.py").write_text(BURN)
    out = tmp_path / "rows.jsonl"
    r = subprocess.run([sys.executable, str(SCRIPT), "--top", "3", "--out", str(out), "--", "-q", "-p",
                        "no:cacheprovider", str(tmp_path / "test_burn.py")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    rows = {row["test"].split("::")[1]: row for row in map(json.loads, out.read_text().splitlines())}
    assert set(rows) == {"test_its_child_burns", "test_idle"}
    assert rows["test_its_child_burns"]["cpu"] >= 0.35, rows   # (its child's 0.4 s of CPU, whatever the load)
    assert rows["test_idle"]["cpu"] < 0.35, rows
    assert "2 tests in" in r.stdout and "test_its_child_burns" in r.stdout.split("test (the 3 dearest)")[1], r.stdout


def test_it_leaves_no_control_group_behind(tmp_path):
    from deepcontact.contest import machine
    (tmp_path / "test_burn.py").write_text(BURN)
    out = tmp_path / "rows.jsonl"
    r = subprocess.run([sys.executable, str(SCRIPT), "--out", str(out), "--", "-q", "-p", "no:cacheprovider", "-n", "1",
                        str(tmp_path / "test_burn.py")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    workers = {row["worker"] for row in map(json.loads, out.read_text().splitlines())}
    found = machine.cgroup_roots().get("cpu")
    left = [n for n in os.listdir(found[1]) if any(n.startswith(f"dc-suite-cpu-{pid}-") for pid in workers)] if found else []
    assert workers and left == [], (workers, left)


def test_process_accounting_records_are_read_as_the_kernel_writes_them(tmp_path):
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        import suite_cpu
    finally:
        sys.path.remove(str(SCRIPT.parent))
    # acct_v3 (linux/acct.h): flag, version, tty, exitcode, uid, gid, pid, ppid, btime, etime, then
    # comp_t utime, stime, mem, io, rw, minflt, majflt, swaps, and the command's 16 bytes
    def record(pid, ppid, forked, utime, stime, comm):
        return (struct.pack("<BBHIIIIIIf", 0x01 if forked else 0, 3, 0, 0, 0, 0, pid, ppid, 0, 0.0)
                + struct.pack("<8H", utime, stime, 0, 0, 0, 0, 0, 0) + comm.ljust(16, b"\0"))
    # comp_t: 13 bits of mantissa, 3 of base-8 exponent: 1 << 13 | 100 is 100 * 8 ticks (8 s at 100 a second)
    data = (record(10, 1, False, 250, 50, b"python3") + record(11, 10, True, (1 << 13) | 100, 0, b"python3")
            + record(12, 11, False, 7, 0, b"bwrap") + record(13, 1, False, 99, 0, b"stranger"))
    path = tmp_path / "acct"
    path.write_bytes(data)
    rows = suite_cpu._accounted(str(path))
    assert rows == [(10, 1, False, "python3", 3.0), (11, 10, True, "python3", 8.0), (12, 11, False, "bwrap", 0.07),
                    (13, 1, False, "stranger", 0.99)]
    assert [r[0] for r in suite_cpu._descendants(rows, 10)] == [10, 11, 12]   # (not another's process)
