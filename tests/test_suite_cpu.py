"""benchmarks/suite_cpu.py charges each test the CPU of what it ran: its own and its processes'."""
import json
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
