"""The reaper (leftovers.kill_descendants, at the end of every dc command) ends whatever still runs
under dc and says how many processes "started under the command (by a plug-in?)" it killed. A
process of one of dc's own sandboxes still there as it searched (bubblewrap, or its namespace's
first process outliving bubblewrap by a moment as dc ends it) was counted and blamed on a plug-in,
intermittently; dc's own are ended without a word, and a plug-in's leftover is still said."""
import subprocess
import sys

import pytest

from deepcontact.contest import machine

SCRIPT = """
import os, subprocess, sys, time
from deepcontact import leftovers
from deepcontact.contest.sandbox import JobSandbox
leftovers.adopt_orphans()
box = JobSandbox(writable=[sys.argv[1]], cwd=sys.argv[1])
box.start(["sleep", "100"])   # (its streams the fence's: relayed pipes)
deadline = time.monotonic() + 30   # (until its namespace's first process and the job run)
while len(leftovers.children(box.process.pid)) == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(0.3)
blamed = leftovers.kill_descendants()   # the search, the sandbox still there
plugins = subprocess.Popen(["sleep", "100"])   # and a process of no sandbox: a plug-in's
print(blamed, leftovers.kill_descendants())
"""


@pytest.mark.skipif(machine.bwrap() is None, reason="no bubblewrap sandbox can be built here")
def test_the_reaper_never_blames_a_plugin_for_dcs_own_sandbox(tmp_path):
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["0", "1"], r.stdout
