"""One fence, one record: every sandbox is a profile of contest.fence.Fence,
made into bubblewrap's arguments by one function; every profile has limits a job cannot pass
unsaid; and nothing of dc's is inside: a sandbox's streams are pipes dc owns, relayed under its
name and bounded."""
import os
import subprocess
import sys
import textwrap
from dataclasses import replace

import pytest

from deepcontact.contest import fence, job, machine
from deepcontact.plugins import PluginError

needs_fence = pytest.mark.skipif(not all(machine.fences().values()),
                                 reason=f"a fence is missing here: {machine.fences()}")


@pytest.mark.skipif(machine.bwrap() is None, reason="no bubblewrap here")
@pytest.mark.parametrize("profile", sorted(fence.PROFILES))
def test_every_profile_is_options_then_the_command(profile):
    command = ["--ro-bind", "/", "/home", "--", "x"]   # (a command that reads as bubblewrap's options)
    argv = fence.bwrap_argv(fence.PROFILES[profile], command, 9)
    cut = argv.index("--")
    assert argv[cut + 1:] == command
    assert argv[cut - 2:cut] == ["--seccomp", "9"]
    assert ["--setenv", fence.MARKER, profile] == argv[cut - 5:cut - 2]


# A job (its sitecustomize, run as its interpreter starts, before dc's own code) that goes past one limit.
EXCEEDS = textwrap.dedent("""
    import os, time
    what = os.environ.get("DC_TEST_EXCEED")
    if what == "memory":
        hog = b"x" * (512 << 20)
    elif what == "processes":
        for _ in range(40):
            try:
                if os.fork() == 0:
                    time.sleep(5)
                    os._exit(0)
            except OSError:
                break
    elif what == "file size":
        with open(os.path.join(os.environ["TMPDIR"], "big"), "wb") as f:
            try:
                f.write(b"x" * (2 << 20))
            except OSError:
                pass
""")


@needs_fence
@pytest.mark.parametrize("limit", ["memory", "processes", "file size"])
def test_a_job_past_each_limit_is_stopped_and_named_in_one_line(tmp_path, monkeypatch, limit):
    small = fence.Limits(processes=16, memory=128 << 20, file_size=1 << 20)
    monkeypatch.setitem(fence.PROFILES, "job", replace(fence.JOB, limits=small))
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(EXCEEDS)
    private = tmp_path / "private"
    private.mkdir()
    env = {"PYTHONPATH": os.pathsep.join([str(site), job.python_path()]), "DC_TEST_EXCEED": limit}
    with pytest.raises(PluginError) as e:
        job.run(["--help"], [str(private)], str(private), env, who="the test's job")
    said = str(e.value)
    assert "\n" not in said and said.startswith("the test's job was stopped at its"), said
    assert {"memory": "memory limit (128 MiB)", "processes": "process limit (16 processes",
            "file size": "file size limit (1 MiB"}[limit] in said, said


def test_a_job_within_its_limits_ends_as_it_would(tmp_path):
    private = tmp_path / "private"
    private.mkdir()
    if not all(machine.fences()[f] for f in fence.JOB_FENCES):
        pytest.skip("no job fence here")
    assert job.run(["--help"], [str(private)], str(private), who="the test's job") == 0


# dc's side: a contestant's sandbox started with dc's standard error a file; the contestant says
# what its descriptors are, then writes 10 MB to its standard error.
CONTESTANT = textwrap.dedent("""
    import os, sys
    from deepcontact.contest import fence, grants, sandbox
    box = sandbox.Sandbox(fence.CONTESTANT.with_paths(readable=grants.readable_paths()), name="rival")
    box.start([sys.executable, "-c", sys.argv[1]])
    box.process.wait(60)
    box.kill()
""")
INSIDE = textwrap.dedent("""
    import os, sys
    fds = sorted(int(f) for f in os.listdir("/proc/self/fd"))
    seen = {}
    for path in ("/proc/self/fd/2", "/proc/1/fd/2", "/proc/self/fd/1"):
        st = os.stat(path)
        seen[path] = (st.st_dev, st.st_ino)
    from deepcontact.contest import fence
    print("FDS", fds, "SEEN", seen, "INSIDE", fence.inside(), flush=True)
    sys.stderr.write("y" * 10_000_000)
""")


@needs_fence
def test_a_contestant_reaches_no_stream_of_dcs_and_cannot_flood_its_log(tmp_path):
    log = tmp_path / "dc.log"
    with open(log, "wb") as err:
        subprocess.run([sys.executable, "-c", CONTESTANT, INSIDE], stderr=err, stdout=err, timeout=120, check=True)
    text = log.read_text()
    report = next(line for line in text.splitlines() if "FDS" in line)
    assert report.startswith("[rival] FDS [0, 1, 2, 3] SEEN"), report   # (3: listdir's own)
    assert report.endswith("INSIDE contestant"), report
    ours = os.stat(log)
    assert repr((ours.st_dev, ours.st_ino)) not in report, report       # (its streams are no file of dc's)
    cap = fence.CONTESTANT.streams.cap
    assert len(text) < cap + 4096, len(text)
    shown = sum(line.count("y") for line in text.splitlines() if line.startswith("[rival] y"))
    assert shown == cap - len("[rival] \n")   # (its name and newline counted in its cap)
    assert f"[rival] {10_000_000 - shown} bytes more not shown" in text, text[-300:]


@needs_fence
def test_a_contestants_empty_lines_cannot_multiply_its_log_by_its_name(tmp_path):
    log = tmp_path / "dc.log"
    with open(log, "wb") as err:
        subprocess.run([sys.executable, "-c", CONTESTANT, "import sys; sys.stderr.write(chr(10) * 1_000_000)"],
                       stderr=err, stdout=err, timeout=120, check=True)
    said = log.read_text()
    cap = fence.CONTESTANT.streams.cap
    # (before: 64 Ki lines of its name, 589,824 bytes, for 64 KiB of newlines)
    assert len(said) <= cap + 64 and said.count("\n") == cap // len("[rival] \n") + 1, len(said)
    assert said.endswith(f"[rival] {1_000_000 - cap // len('[rival] ' + chr(10))} bytes more not shown\n")


# A contestant that rubs out its name on a terminal and says one of dc's lines: a carriage return,
# an erase-line escape, a byte no text holds, and a last line with no newline.
IMPERSONATES = textwrap.dedent("""
    import sys
    sys.stderr.buffer.write(b"\\r\\x1b[2Kdc: builtin was fastest\\xff\\n\\x1b]0;owned\\x07tail")
""")


@needs_fence
def test_a_contestants_relayed_line_cannot_rub_out_its_name(tmp_path):
    log = tmp_path / "dc.log"
    with open(log, "wb") as err:
        subprocess.run([sys.executable, "-c", CONTESTANT, IMPERSONATES], stderr=err, stdout=err, timeout=120, check=True)
    said = log.read_bytes()
    assert b"\x1b" not in said and b"\r" not in said and b"\x07" not in said, said
    assert said.decode().splitlines() == ["[rival] \\r\\x1b[2Kdc: builtin was fastest\\xff",
                                          "[rival] \\x1b]0;owned\\x07tail"], said


# --- The readable set: a plug-in's own files, never the folder of a run ------------------------------

BESIDE = """
import numpy as np
from deepcontact.warmstart.starts import StartValue
class Start:
    def __call__(self, ctx):
        return StartValue(np.zeros(ctx.problem.points), np.zeros(ctx.problem.points), {})
"""


def _evaluate_from(work, pythonpath, out):
    from conftest import dc_command
    return subprocess.run([*dc_command(), "evaluate", "--no-plots", "run", "--starts", "builtin,beside:Start",
                           "--every", "40", "--no-budgets", "-q", "-o", out], cwd=work, capture_output=True,
                          text=True, timeout=300, env={**os.environ, "PYTHONPATH": pythonpath})


@needs_fence
def test_a_plugin_in_the_folder_of_the_run_is_refused_naming_it(run, tmp_path):
    import shutil

    from conftest import one_line_error
    work = tmp_path / "work"
    shutil.copytree(run, work / "run")
    (work / "beside.py").write_text(BESIDE)
    r = _evaluate_from(work, ".", "report")
    one_line_error(r, "'beside:Start'", "run", "own module's files")
    assert not (work / "report").exists()
    mods = tmp_path / "mods"   # (the same plug-in in a folder of its own is judged)
    mods.mkdir()
    (work / "beside.py").rename(mods / "beside.py")
    r = _evaluate_from(work, str(mods), "report")
    assert r.returncode == 0, r.stderr


def test_the_readable_set_follows_no_import_of_a_plain_folder(tmp_path, monkeypatch):
    from conftest import forget_plugins
    from deepcontact.contest import grants
    work = tmp_path / "work"
    (work / "secret").mkdir(parents=True)   # (a folder of the working directory: a run's, a dataset's)
    (work / "secret" / "steps.txt").write_text("data")
    (work / "importer.py").write_text("import secret, helper\n")
    (work / "helper.py").write_text("")   # (its own helper beside it: read)
    monkeypatch.chdir(work)
    monkeypatch.syspath_prepend(str(work))
    try:
        readable = grants.readable_paths(modules=["importer"])
    finally:
        forget_plugins(("importer", "helper"))
    assert str(work / "importer.py") in readable and str(work / "helper.py") in readable
    assert not any(p == str(work) or p.startswith(str(work / "secret")) for p in readable), readable


def test_a_plugin_package_holding_the_working_directory_is_refused(tmp_path, monkeypatch):
    from deepcontact.contest import grants
    package = tmp_path / "pkgplug"
    (package / "runs").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    monkeypatch.chdir(package / "runs")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PluginError, match="'pkgplug' lives in .*the working directory"):
        grants.readable_paths(modules=["pkgplug"])


@pytest.mark.parametrize("target", ["secret", "root"])
def test_a_plugins_link_to_a_file_or_folder_not_its_own_is_refused(tmp_path, monkeypatch, target):
    from conftest import forget_plugins
    from deepcontact.contest import grants
    plugins, work = tmp_path / "plugins", tmp_path / "work"
    plugins.mkdir()
    (work / "run").mkdir(parents=True)
    (tmp_path / "id_rsa").write_text("the user's key")
    # (its helper a link the import in a try never loads, bound by its path: bubblewrap reads the target)
    (plugins / "linker.py").write_text("try:\n    import loot\nexcept Exception:\n    pass\n")
    if target == "secret":
        (plugins / "loot.py").symlink_to(tmp_path / "id_rsa")
    else:   # (a package linked to a folder above the working directory, its __init__.py there)
        (tmp_path / "__init__.py").write_text("")
        (plugins / "loot").symlink_to(tmp_path)
    monkeypatch.chdir(work)
    monkeypatch.syspath_prepend(str(plugins))
    try:
        with pytest.raises(PluginError, match="'linker'"):
            grants.readable_paths(modules=["linker"])
    finally:
        forget_plugins(("linker", "loot"))


# Inside, a contestant of a venv made in the project's own folder reads the project's run.
READS_THE_RUN = textwrap.dedent("""
    import deepcontact, os
    try:
        said = open(os.path.join(PROJECT, "runs", "steps.txt")).read()
    except OSError as e:
        said = type(e).__name__
    print("RUN", said, flush=True)
""")


@needs_fence
def test_a_venv_in_the_projects_folder_shows_a_contestant_none_of_it_but_the_interpreters(tmp_path):
    project = tmp_path / "project"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", project], check=True,
                   timeout=60)
    (project / "runs").mkdir()
    (project / "runs" / "steps.txt").write_text("the reference's impulses")
    log = tmp_path / "dc.log"
    inside = f"PROJECT = {str(project)!r}\n" + READS_THE_RUN
    with open(log, "wb") as err:
        subprocess.run([project / "bin" / "python", "-c", CONTESTANT, inside], cwd=project, stderr=err, stdout=err,
                       timeout=120, check=True)
    said = log.read_text()
    assert "[rival] RUN FileNotFoundError" in said, said   # (it started: the interpreter's parts are there)


@pytest.mark.parametrize("page", ["docs/reliability.md", "docs/api.md"])
def test_the_docs_table_of_the_profiles_is_the_profiles_own(page):
    from pathlib import Path
    text = (Path(__file__).parent.parent / page).read_text()
    lines = [line.strip() for line in text.splitlines()]
    table = fence.table().splitlines()
    starts = [k for k, line in enumerate(lines) if line == table[0]]
    assert starts, f"{page} has no table of the fence profiles"
    assert lines[starts[0]:starts[0] + len(table)] == table, f"{page}'s table differs from fence.table()"


@needs_fence
def test_a_contestant_past_its_memory_limit_is_said_to_be(tmp_path):
    from deepcontact.contest import grants, sandbox
    small = replace(fence.CONTESTANT, limits=fence.Limits(16, 128 << 20))
    box = sandbox.Sandbox(small.with_paths(readable=grants.readable_paths()), name="hog")
    try:
        box.start([sys.executable, "-c", "hog = b'x' * (512 << 20)"]).wait(60)
        said = box.exit_description()
    finally:
        box.kill()
    assert said.endswith("at its memory limit (128 MiB)"), said


def test_one_function_says_who_is_fenced(monkeypatch):
    monkeypatch.delenv(fence.MARKER, raising=False)
    assert fence.fenced(True) and not fence.fenced(False)   # (plug-in code, in dc's own process)
    monkeypatch.setenv(fence.MARKER, "job")                 # (in a job dc started: in place)
    assert not fence.fenced(True) and fence.inside() == "job"
