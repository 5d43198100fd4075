"""Timings a reader can trust and no silent subsets: every report says how it was measured
(threads, -j, versions, CPU, load, command), the closed loop runs every simulation it is given,
and a tolerance without a cap converges instead of stopping at the scene's 8 sweeps."""
import json
import subprocess
import sys

import pytest
import torch

from conftest import HOSTILE_PILE
from test_mutations import invoke


def test_every_evaluate_report_records_its_protocol(run, tmp_path):
    r = invoke("evaluate", "--no-plots", run, "--starts", "builtin", "--every", "30", "--no-budgets", "--threads", "2",
               "-q", "-o", tmp_path / "r")
    assert r.exit_code == 0, r.stderr
    p = json.loads((tmp_path / "r" / "summary.json").read_text())["settings"]["protocol"]
    assert p["threads"] == 2 and p["jobs"] == 1 and p["cpu"] and p["cores"] >= 1
    assert set(p["versions"]) == {"deepcontact", "box2d", "box2d3", "numpy", "torch", "python", "pymunk", "mujoco"}
    from deepcontact import _box2d
    assert p["versions"]["box2d3"] == getattr(_box2d, "box2d3_version", None)   # (None in a build without v3)
    assert all(v for k, v in p["versions"].items() if k not in ("box2d3", "pymunk", "mujoco"))
    assert len(p["load_average"]) == 3
    text = (tmp_path / "r" / "report.md").read_text()
    assert "Measured with 2 torch threads per process and 1 worker process (-j)" in text
    torch.set_num_threads(1)


HELD_TO = """
import os
import numpy as np
from deepcontact.warmstart.starts import StartValue
class Start:
    def __call__(self, ctx):
        if os.sched_getaffinity(0) != {HELD}:   # (in the contestant's own process)
            raise ValueError(f"this contestant may run on CPUs {sorted(os.sched_getaffinity(0))}")
        return StartValue(np.zeros(ctx.problem.points), np.zeros(ctx.problem.points), {})
"""


def test_a_measurement_held_to_fewer_cpus_says_which_and_its_contestants_run_there(run, tmp_path, monkeypatch):
    # (taskset -c N: the contestants' sandboxes run where the judge is held, forked from a zygote
    # started before it was or not, and the report says where its times were taken)
    import os
    from conftest import hold_threads, plugin_modules
    every = os.sched_getaffinity(0)
    if os.cpu_count() < 2 or len(every) < 2:
        pytest.skip("needs two CPUs to hold the command to one")
    one = max(every)
    r = invoke("evaluate", "--no-plots", run, "--starts", "builtin", "--every", "40", "--no-budgets", "-q",
               "-o", tmp_path / "before")   # (a zygote started where every CPU is allowed, where forks are made)
    assert r.exit_code == 0, r.stderr
    forget = plugin_modules(tmp_path, monkeypatch, {"held_to": HELD_TO.replace("HELD", str(one))})
    hold_threads({one})
    try:
        r = invoke("evaluate", "--no-plots", run, "--starts", "builtin,held_to:Start", "--every", "30", "--no-budgets",
                   "-q", "-o", tmp_path / "r")
    finally:
        hold_threads(every)
        forget()
    assert r.exit_code == 0, r.stderr
    p = json.loads((tmp_path / "r" / "summary.json").read_text())["settings"]["protocol"]
    assert p["cpus"] == [one]
    assert f"({p['cores']} cores; run on CPU {one} only; load average" in (tmp_path / "r" / "report.md").read_text()
    # and where it may run anywhere, nothing is said of it
    from deepcontact.protocol import _ranges, current, protocol_line
    assert current()["cpus"] == sorted(every)
    if len(every) == os.cpu_count():
        assert " only;" not in protocol_line(current())
    assert _ranges([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"


THREADS_SEEN = """
import os
import numpy as np
import torch
from deepcontact.warmstart.starts import StartValue
AT_IMPORT = torch.get_num_threads()   # (torch imported here, under the contestant's filter)
class Start:
    def __call__(self, ctx):
        if torch.get_num_threads() != 3:   # (the judge's --threads, in the contestant's own process)
            raise ValueError(f"this contestant has {torch.get_num_threads()} torch threads")
        if AT_IMPORT != 3:   # (MKL, which counts cores by moving itself to each, which it may not, is told)
            raise ValueError(f"torch took {AT_IMPORT} threads at its import")
        pools = {v: os.environ.get(v) for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
        if set(pools.values()) != {"3"}:   # (numpy's pool too, sized before its import)
            raise ValueError(f"this contestant's thread pools were told {pools}")
        return StartValue(np.zeros(ctx.problem.points), np.zeros(ctx.problem.points), {})
"""


def test_threads_asked_reach_every_contestant(run, tmp_path, monkeypatch):
    from conftest import plugin_modules
    forget = plugin_modules(tmp_path, monkeypatch, {"threads_seen": THREADS_SEEN})
    try:
        r = invoke("evaluate", "--no-plots", run, "--starts", "threads_seen:Start", "--every", "40", "--no-budgets",
                   "--threads", "3", "-q", "-o", tmp_path / "r")
        assert r.exit_code == 0, r.stderr
    finally:
        forget()
        torch.set_num_threads(1)


def test_the_default_is_one_thread_whatever_the_machine(run, model, tmp_path):
    torch.set_num_threads(2)   # torch's default on a larger machine: the command's own default wins
    r = invoke("evaluate", "--no-plots", run, "--starts", "cnn", "--checkpoint", model / "best.pt", "--every", "40",
               "--no-budgets", "-q", "-o", tmp_path / "r")
    assert r.exit_code == 0, r.stderr
    assert torch.get_num_threads() == 1
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["settings"]["protocol"]["threads"] == 1


def test_the_closed_loop_runs_every_simulation(run, tmp_path):
    args = ["evaluate", "--no-plots", run, "--closed-loop", "--starts", "builtin", "--steps", "30", "--no-budgets",
            "-q"]
    assert invoke(*args, "-o", tmp_path / "one").exit_code == 0
    assert invoke(*args, "-j", "2", "-o", tmp_path / "two").exit_code == 0
    text = (tmp_path / "one" / "report.md").read_text()
    assert "2 simulations" in text and "seed 0" in text and "seed 1" in text, text
    rows = [line for line in text.splitlines() if line.startswith("| builtin")]
    assert len(rows) == 3   # pooled, then each simulation's
    one = json.loads((tmp_path / "one" / "closed-loop.json").read_text())
    two = json.loads((tmp_path / "two" / "closed-loop.json").read_text())
    assert [r["iterations"] for r in one["results"]] == [r["iterations"] for r in two["results"]]
    pooled, first, second = one["results"]
    assert pooled["iterations"] == first["iterations"] + second["iterations"]
    assert max(pooled["drift"]) == max(max(first["drift"]), max(second["drift"]))
    assert one["protocol"]["threads"] == 1


def test_a_tolerance_without_a_cap_converges_and_a_short_cap_is_counted(tmp_path):
    r = invoke("simulate", *HOSTILE_PILE, "--steps", "60", "--solver", "pgs", "--tolerance", "1e-6", "-q",
               "-o", tmp_path / "a")
    assert r.exit_code == 0, r.stderr
    m = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert m["pgs"]["max_iterations"] == 1000 and m["simulations"][0]["capped"] == 0
    dense = ["pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4"]
    r = invoke("simulate", *dense, "--steps", "150", "--solver", "pgs", "--tolerance", "1e-9",
               "--max-iterations", "2", "-o", tmp_path / "b")
    assert r.exit_code == 0, r.stderr
    capped = json.loads((tmp_path / "b" / "manifest.json").read_text())["simulations"][0]["capped"]
    assert capped > 50 and f"{capped} of 150 steps stopped at the cap of 2 sweeps" in r.stderr, r.stderr


def test_python_dash_m_deepcontact_is_dc():
    r = subprocess.run([sys.executable, "-m", "deepcontact", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.startswith("dc, version"), r.stdout + r.stderr


INAPPLICABLE = [
    # (command and arguments up to the options, the option given, its value or None for a flag)
    (["evaluate", "{run}", "--starts", "builtin", "-o", "{tmp}/r"], "--steps", "5"),
    (["evaluate", "{run}", "--starts", "builtin", "--closed-loop", "-o", "{tmp}/r"], "--every", "3"),
    (["evaluate", "{run}", "--starts", "builtin", "-o", "{tmp}/r"], "--checkpoint", "{model}/best.pt"),
    (["evaluate", "{run}", "--starts", "builtin", "-o", "{tmp}/r"], "--cell", "1"),
    (["evaluate", "{run}", "--starts", "cnn", "--checkpoint", "{model}/best.pt", "-o", "{tmp}/r"], "--kernel", "spiky"),
    (["evaluate", "{run}", "--starts", "builtin", "-o", "{tmp}/r"], "--seed", "3"),
    (["train", "{data}", "-o", "{tmp}/m"], "--no-final-relu", None),
    (["train", "{data}", "--arch", "thesis", "-o", "{tmp}/m"], "--width", "8"),
    (["train", "{data}", "-o", "{tmp}/m"], "--lr", "0.1"),
    (["train", "{data}", "-o", "{tmp}/m"], "--solver-sweeps", "3"),
    (["simulate", "pile", "--seeds", "0..1", "-o", "{tmp}/s"], "--seed", "4"),
    (["simulate", "pile", "-o", "{tmp}/s"], "--shard", "0/2"),
    (["simulate", "pile", "--write-scene", "{tmp}/scene.xml"], "-o", "{tmp}/s"),
    (["simulate", "pile", "--solver", "pgs", "-o", "{tmp}/s"], "--iterations", "20"),
    (["simulate", "pile", "-o", "{tmp}/s"], "--tolerance", "1e-4"),
    (["simulate", "pile", "--engine", "pymunk", "-o", "{tmp}/s"], "--substeps", "4"),
    (["simulate", "pile", "--engine", "mujoco", "-o", "{tmp}/s"], "--solver", "pgs"),
    (["render", "{step}", "-o", "{tmp}/p.png"], "--every", "2"),
    (["render", "{step}", "-o", "{tmp}/p.png"], "--fps", "10"),
    (["render", "{run}", "-o", "{tmp}/p.gif"], "--sample", "2"),
    (["render", "{data}", "-o", "{tmp}/p.png"], "--color-by", "speed"),
    (["render", "{step}", "-o", "{tmp}/p.png"], "--threads", "2"),
    (["export", "{run}", "--format", "csv", "-o", "{tmp}/t"], "--solution", "recorded"),
    (["render", "{run}", "-o", "{tmp}/v.html"], "-j", "2"),
    (["simulate", "pile", "--solver", "pgs", "--mode", "exact", "-o", "{tmp}/s"], "--relaxation", "1.3"),
    (["simulate", "pile", "--solver", "pgs", "--mode", "exact", "-o", "{tmp}/s"], "--accelerate", "nncg"),
]


@pytest.mark.parametrize("args,option,value", INAPPLICABLE, ids=lambda x: x if isinstance(x, str) else None)
def test_an_option_that_does_not_apply_is_refused(run, dataset, model, tmp_path, args, option, value):
    step = sorted(run.glob("seed-000000/step-*.xml"))[-1]
    fill = dict(run=run, data=dataset, model=model, tmp=tmp_path, step=step)
    argv = [a.format(**fill) for a in args] + [option] + ([] if value is None else [value.format(**fill)])
    r = invoke(*argv)
    assert r.exit_code == 2 and "Traceback" not in r.stderr, (argv, r.stderr)
    assert option in r.stderr and ("appl" in r.stderr or "give one" in r.stderr or "is Box2D" in r.stderr), r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []   # refused before anything was written


def test_the_loops_rules_are_the_librarys_for_the_command_line_and_code_alike():
    """One check of the loop's options (SolveSettings' own and simulate.pgs_loop.check_loop's): dc
    simulate exits 2 with it, and a PGSStepper built in code refuses the same options with the same
    words."""
    import pytest
    from deepcontact.errors import OptionError
    from deepcontact.scene.generators import generate
    from deepcontact.simulate.build import build_world
    from deepcontact.simulate.pgs_loop import PGSStepper, check_loop
    from deepcontact.solver.settings import SolveSettings
    cases = [(dict(mode="exact", relaxation=1.3), "--relaxation"), (dict(mode="exact", relaxation="auto",
             tolerance=1e-4), "--relaxation"), (dict(mode="exact", accelerate="nncg"), "--accelerate"),
             (dict(mode="float32", accelerate="newton"), "--accelerate"),
             (dict(relaxation="auto", tolerance=0), "--relaxation"), (dict(start="lucky"), "--start")]
    scene = generate("pile", 0, {"count": 4, "steps": 5})

    def loop(kw):   # (made and checked as the loop would: the settings first, then the loop's rules)
        kw = dict(kw)
        start = kw.pop("start", "builtin")
        check_loop(SolveSettings(**kw), start)
        return SolveSettings(**kw), start
    for kw, option in cases:
        with pytest.raises(OptionError) as e:
            loop(kw)
        assert e.value.option == option
        with pytest.raises(OptionError):
            PGSStepper(build_world(scene), scene, *loop(kw))
    loop(dict(mode="float64", relaxation="auto", tolerance=1e-4, accelerate="newton"))
