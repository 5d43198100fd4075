"""A fenced job (a study, a plug-in network's training or drawing) is a fork of the jobs' zygote
(contest/zygote.py, forked.py): an interpreter with numpy (and, for a training or a drawing, torch)
loaded once, in a sandbox of its own, each job a fork that fences itself by the job's own fence record before dc's command runs. What
the job sees and may do is what a fresh sandbox's job sees and may do: each probe below runs both
ways, forked and fresh (DC_NO_ZYGOTE=1), and their findings must agree, but for the one thing that
tells them apart (the namespace's first process: the zygote's fork, or bubblewrap)."""
import json
import os
import re
import sys
import textwrap

import pytest

from conftest import dc, hold_threads
from deepcontact.contest import fence as fence_records, fences, job, sandbox, zygote

pytestmark = pytest.mark.skipif(not all(fences().values()), reason=f"a fence is missing here: {fences()}")

PROBE = textwrap.dedent("""
    import ctypes, json, os, resource, socket, sys, tempfile
    import click
    from deepcontact.studies import Study

    def _tried(action):
        try:
            action()
            return "done"
        except OSError as e:
            return type(e).__name__

    def _write(path):
        with open(path, "w") as f:
            f.write("x")
        os.remove(path)

    @click.command("probe")
    @click.option("-o", "--output", "out")
    @click.option("--user-folder")
    @click.option("--torch", "with_torch", is_flag=True)
    def probe(out, user_folder, with_torch):
        '''Writes what its fence lets it see and do.'''
        libc = ctypes.CDLL(None, use_errno=True)
        seen = {
            "first process": os.path.basename(open("/proc/1/cmdline").read().split(chr(0))[0]),
            "uid": [os.getuid(), os.getgid()],
            "profile": os.environ.get("DC_FENCE"),
            "tmpdir is TMPDIR": tempfile.gettempdir() == os.environ["TMPDIR"],
            "TMPDIR written": _tried(lambda: _write(os.path.join(os.environ["TMPDIR"], "x"))),
            "cwd": os.getcwd(),
            "path first": sys.path[0],
            "user folder written": _tried(lambda: _write(os.path.join(user_folder, "x"))),
            "/tmp written": _tried(lambda: _write("/tmp/dc-job-probe-x")),
            "processes": len([p for p in os.listdir("/proc") if p.isdigit()]) <= 3,
            "unix socket": _tried(lambda: socket.socket(socket.AF_UNIX)),
            "new user namespace": libc.unshare(0x10000000) == 0,
            "clone of a namespace": libc.syscall(56, 0x10000000 | 17, 0, 0, 0, 0) >= 0,
            "file size limit": resource.getrlimit(resource.RLIMIT_FSIZE)[0],
            "writable mounts": sorted(
                line.split()[4] for line in open("/proc/self/mountinfo")
                if "rw" in line.split()[5].split(",") and line.split()[4] not in ("/proc", "/dev", "/dev/shm")
                and not line.split()[4].startswith(("/proc/", "/dev/"))),
            "variables": sorted(k for k in os.environ if k not in ("PWD", "OLDPWD", "_", "DC_NO_ZYGOTE")),
            "argv": sys.argv[1:],
            "click": click.__file__,
        }
        if with_torch:   # (what torch's compiler looked up as it loaded: the job's own, as a fresh one's)
            import torch._dynamo.config, torch._dynamo.package
            seen["compiler cache"] = torch._dynamo.package.DynamoCache._path_prefix
            seen["compiler debug"] = torch._dynamo.config.debug_dir_root
            seen["zygote folders kept"] = sorted(
                f"{name}.{key}" for name, module in list(sys.modules.items()) if name.startswith("torch") and module
                for key, value in list(vars(module).items()) if isinstance(value, str) and value.startswith("/dev/shm"))
        with open(out, "w") as f:
            json.dump(seen, f)

    class Probe(Study):
        name, summary, order, writes = "probe", "writes what its fence lets it do", 92, "file"
        command = staticmethod(lambda: probe)
""")


@pytest.fixture
def probe(tmp_path, monkeypatch):
    lib = tmp_path / "lib"
    info = lib / "dc_job_probe-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dc-job-probe\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[deepcontact.studies]\nprobe = dc_job_probe:Probe\n")
    (lib / "dc_job_probe.py").write_text(PROBE)
    monkeypatch.syspath_prepend(str(lib))
    yield lib
    sys.modules.pop("dc_job_probe", None)


def _probed(tmp_path, name, *extra):
    user = tmp_path / "user"
    user.mkdir(exist_ok=True)
    (tmp_path / name).mkdir()
    out = tmp_path / name / "probe.json"
    r = dc("study", "probe", "-o", out, "--user-folder", user, *extra)
    assert r.returncode == 0, r.stderr
    return json.loads(out.read_text())


def _normalised(seen):
    """What must agree between a forked and a fresh job: their own folders' names aside."""
    seen = dict(seen)
    seen["argv"] = [re.sub(r"/(forked|fresh)/(\.probe\.json\.partial)-[0-9]+-[a-z0-9_]+/", r"/\2/", a) for a in seen["argv"]]
    seen["writable mounts"] = [re.sub(r"-[0-9]+-[a-z0-9_]+$", "", os.path.basename(p)) for p in seen["writable mounts"]]
    return seen


def test_a_forked_job_sees_and_may_do_what_a_fresh_one_does(probe, tmp_path, monkeypatch):
    forked = _probed(tmp_path, "forked")
    monkeypatch.setenv("DC_NO_ZYGOTE", "1")
    fresh = _probed(tmp_path, "fresh")
    # (the namespace's first process: the zygote's fork, an interpreter, or bubblewrap)
    assert forked.pop("first process").startswith("python") and fresh.pop("first process") == "bwrap"
    assert forked["uid"] == [os.getuid(), os.getgid()] and forked["profile"] == "job"
    assert forked["tmpdir is TMPDIR"] and forked["TMPDIR written"] == "done"
    assert forked["cwd"] == forked["path first"] == os.getcwd()
    assert forked["user folder written"] == forked["/tmp written"] == "OSError"
    assert forked["processes"] and forked["unix socket"] == "PermissionError"
    assert not forked["new user namespace"] and not forked["clone of a namespace"]
    assert forked["file size limit"] == fence_records.JOB.limits.file_size
    # (its TMPDIR, its output's staging folder, the study's units kept beside the output)
    assert len(forked["writable mounts"]) == 3, forked["writable mounts"]
    assert _normalised(forked) == _normalised(fresh)


TORCH_PROBE = """
import json, os, sys
before = "torch" in sys.modules
import torch._dynamo.config, torch._dynamo.package
seen = {"torch mapped before": before,
        "compiler cache": torch._dynamo.package.DynamoCache._path_prefix,
        "compiler debug": torch._dynamo.config.debug_dir_root,
        "zygote folders kept": sorted(f"{name}.{key}" for name, module in list(sys.modules.items())
                                      if name.startswith("torch") and module for key, value in list(vars(module).items())
                                      if isinstance(value, str) and value.startswith("/dev/shm"))}
os.write(int(sys.argv[1]), json.dumps(seen).encode())
"""


def _job_wrote(tmp_path, name, script, profile="job"):
    """What `script` (run as `python -c script FD`) wrote to FD in a job of this profile, forked
    from the jobs' zygote where it can be."""
    private = tmp_path / name
    private.mkdir()
    box = sandbox.JobSandbox(writable=[private], profile=profile)
    env = dict(os.environ, TMPDIR=str(private), PYTHONPATH=job.python_path())
    read, write = os.pipe()
    try:
        job.start(box, ["-c", script, str(write)], write, env)
        os.close(write)
        write = None
        assert box.process.wait() == 0
    finally:
        box.kill()
        if write is not None:
            os.close(write)
    with os.fdopen(read, "rb") as f:
        return json.loads(f.read())


def _training_job(tmp_path, name):
    """What TORCH_PROBE finds in a job of the training profile (forked from the torch zygote)."""
    return _job_wrote(tmp_path, name, TORCH_PROBE, "training")


def test_torchs_compiler_in_a_forked_training_job_looks_where_a_fresh_ones_does(tmp_path, monkeypatch):
    # (torch sets this as its compiler loads: here, where this process loaded it, neither job looks)
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    forked = _training_job(tmp_path, "forked")
    monkeypatch.setenv("DC_NO_ZYGOTE", "1")
    fresh = _training_job(tmp_path, "fresh")
    assert forked["torch mapped before"] and not fresh["torch mapped before"]   # (the torch zygote's fork)
    assert forked["zygote folders kept"] == [] == fresh["zygote folders kept"]
    assert forked["compiler debug"] == fresh["compiler debug"] == os.path.join(os.getcwd(), "torch_compile_debug")
    # (under each job's own TMPDIR, a private folder of its own)
    assert forked["compiler cache"].startswith(str(tmp_path / "forked"))
    assert fresh["compiler cache"].startswith(str(tmp_path / "fresh"))
    assert forked["compiler cache"][len(str(tmp_path / "forked")):] == fresh["compiler cache"][len(str(tmp_path / "fresh")):]


def test_a_job_whose_path_holds_its_own_copy_of_a_zygotes_library_starts_fresh_and_imports_it(
        probe, tmp_path, monkeypatch):
    import shutil

    import click
    shadow = tmp_path / "shadow"
    shutil.copytree(os.path.dirname(click.__file__), shadow / "click")
    monkeypatch.syspath_prepend(str(shadow))   # (the job's PYTHONPATH: the caller's path, first)
    seen = _probed(tmp_path, "shadowed")
    assert seen["click"] == str(shadow / "click" / "__init__.py") and seen["first process"] == "bwrap"


def test_a_job_whose_fork_cannot_be_asked_for_starts_fresh_and_runs(tmp_path, monkeypatch, caplog):
    # (more writable folders than one request to the zygote carries: a real refusal, then a fresh start)
    monkeypatch.setattr(zygote, "_job_refused", [])
    folders = [tmp_path / f"w{i}" for i in range(12)]
    for f in folders:
        f.mkdir()
    with caplog.at_level("INFO", logger="deepcontact.contest.zygote"):
        code = job.run(["--version"], [str(f) for f in folders], str(folders[0]))
    assert code == 0
    assert "jobs start as fresh sandboxes: more writable folders than a request carries (12)" in caplog.text


def test_a_jobs_zygote_of_another_environment_is_ended_once_none_of_its_jobs_runs(tmp_path, monkeypatch):
    private = tmp_path / "private"
    private.mkdir()
    for value in ("1", "2"):   # (a variable a library might read as it loads: a zygote of its own)
        monkeypatch.setenv("DC_JOB_ZYGOTE_TEST", value)   # (a job's own: no new zygote)
        monkeypatch.setenv("JOB_ZYGOTE_TEST", value)
        assert job.run(["--version"], [str(private)], str(private)) == 0
    kept = [key for key, made in zygote._zygotes.items() if key[0] == "job" and not key[2] and made.alive()]
    assert len(kept) == 1 and ("JOB_ZYGOTE_TEST", "2") in kept[0][1]
    assert all(key[0] != "DC_JOB_ZYGOTE_TEST" for key in kept[0][1])


AFFINITY_PROBE = "import json, os, sys; os.write(int(sys.argv[1]), json.dumps(sorted(os.sched_getaffinity(0))).encode())"


def _job_cpus(tmp_path, name):
    """The CPUs a job of the study profile (forked from the jobs' zygote) may run on."""
    return _job_wrote(tmp_path, name, AFFINITY_PROBE)


def test_a_forked_job_runs_on_the_cpus_of_the_thread_that_asks_for_it(tmp_path):
    # (as a fresh sandbox inherits them: `taskset -c 1 dc study ...` holds its jobs to CPU 1, though
    # the jobs' zygote was started before, where every CPU was allowed)
    every = os.sched_getaffinity(0)
    if len(every) < 2:
        pytest.skip("needs two CPUs to hold the command to one")
    assert _job_cpus(tmp_path, "before") == sorted(every)   # (the zygote started, or kept, unpinned)
    one = max(every)
    hold_threads({one})
    try:
        assert _job_cpus(tmp_path, "held") == [one]
    finally:
        hold_threads(every)
