"""The second hostile audit's classes, each with generated inputs (not only the audit's examples):
nothing lost, nothing injected into a page, no traceback, nothing silently wrong, no unbounded
memory, and messages with the right exit code. Commands run in-process (click's runner) except
where a real process is the point (a kill, a browser).
"""
import gzip
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st
from lxml import html as lxml_html

from conftest import HOSTILE_PILE, snapshot
from deepcontact import output
from deepcontact.errors import InputError
from test_mutations import assert_clean as _assert_clean, invoke

SETTINGS = settings(max_examples=int(os.environ.get("DC_MUTATIONS", "12")), deadline=None,
                    derandomize="DC_MUTATIONS" not in os.environ,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_browser = [pytest.mark.process,
                 pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make setup)")]


def assert_clean(result, out):
    """test_mutations' contract, and the message is one of ours (not the catch-all's)."""
    _assert_clean(result, out)
    assert "not a message of ours" not in result.stderr, result.stderr


def one_line(result, code=1, *needles):
    assert result.exit_code == code, (result.exit_code, result.stderr)
    assert "not a message of ours" not in result.stderr, result.stderr
    err = result.stderr.strip()
    assert "Traceback" not in err and len(err.splitlines()) == (1 if code == 1 else len(err.splitlines())), err
    for n in needles:
        assert str(n) in err, (n, err)
    return err


# --- Data loss: ownership by record, never by name --------------------------------------------

NAME = st.text(st.sampled_from("abcXYZ019._-~ "), min_size=1, max_size=12).filter(lambda s: s not in (".", ".."))
USER_PATHS = st.builds(lambda hidden, name, suffix, nested: ("seed-000000/" if nested else "")
                       + ("." if hidden else "") + name + suffix,
                       st.booleans(), NAME, st.sampled_from([".tmp", ".lock", ".partial-12", ".old-3", ".swap",
                                                             ".json", ".xml", ""]), st.booleans())


@SETTINGS
@given(rel=USER_PATHS)
def test_overwrite_never_takes_a_users_file_for_its_own(tmp_path_factory, rel):
    tmp = tmp_path_factory.mktemp("own")
    out = tmp / "out"
    with output.output_folder(out, output.Owned("run"), command="simulate") as work:
        (work / "seed-000000").mkdir()
        (work / "seed-000000" / "step-000000.xml").write_text("<step/>")
    if rel.split("/")[-1] in ("step-000000.xml", output.RECORD):
        return
    (out / rel).write_text("the user's")
    before = snapshot(out)
    with pytest.raises(InputError) as e:
        with output.output_folder(out, output.Owned("run"), overwrite=True, command="simulate"):
            pass
    assert "not written by dc simulate" in str(e.value) and snapshot(out) == before
    assert sorted(p.name for p in tmp.iterdir()) == ["out"]


KILL_AT = ["moved aside", "swapped", "old removed"]


@pytest.mark.parametrize("when", KILL_AT)
def test_a_kill_at_any_point_of_a_replacement_loses_nothing(tmp_path, when):
    """SIGKILL (no clean-up runs) at each point of the swap; the next command finds the earlier
    output or the new one, whole, and nothing of ours beside it."""
    out = tmp_path / "out"
    with output.output_folder(out, output.Owned("report"), command="evaluate") as work:
        (work / "report.md").write_text("old")
    script = f"""
import os, signal, sys
from deepcontact import output
from deepcontact.output import swap
when = {when!r}
real_replace, real_rmtree = os.replace, swap.remove_tree_quietly
def replace(src, dst, **kw):
    real_replace(src, dst, **kw)
    if (when == "moved aside" and ".old-" in str(dst)) or (when == "swapped" and str(dst) == {str(out)!r}):
        os.kill(os.getpid(), signal.SIGKILL)
def rmtree(p):
    if when == "old removed" and ".old-" in str(p):
        os.remove(os.path.join(p, "report.md")); os.kill(os.getpid(), signal.SIGKILL)
    real_rmtree(p)
os.replace, swap.remove_tree_quietly = replace, rmtree
with output.output_folder({str(out)!r}, output.Owned("report"), overwrite=True, command="evaluate") as work:
    (work / "report.md").write_text("new")
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert r.returncode == -signal.SIGKILL, r.stderr
    with output.output_folder(out, output.Owned("report"), overwrite=True, command="evaluate") as work:
        # the recovery ran under the lock: the output is whole, old or new, and alone
        assert (out / "report.md").read_text() == ("old" if when == "moved aside" else "new")
        assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".out.partial-")) == \
            [".out.lock", "out"]
        (work / "report.md").write_text("newer")
    assert (out / "report.md").read_text() == "newer" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def special_file(path, kind):
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(path))
        s.close()
    elif kind == "folder":
        path.mkdir()
    else:
        path.symlink_to(path.parent / "target")
        (path.parent / "target").write_text("linked")


@pytest.mark.parametrize("kind", ["fifo", "socket", "folder", "symlink"])
def test_single_file_outputs_never_replace_a_special_file(run, tmp_path, kind):
    step = sorted(run.glob("seed-000000/step-*.xml"))[-1]
    for name, args in (("x.png", ["render", step]), ("x.gif", ["render", run, "--every", "40"]),
                       ("x.html", ["render", run, "--every", "40"]), ("scene.xml", ["simulate", *HOSTILE_PILE]),
                       ("table.md", ["study", "stability", "--fast"])):
        target = tmp_path / kind / name
        target.parent.mkdir(exist_ok=True)
        special_file(target, kind)
        flag = "--write-scene" if args[0] == "simulate" else "-o"
        r = invoke(*args, flag, target, "--overwrite")
        # (a folder may be refused by click's own path check already: a bad option value, exit 2)
        one_line(r, 2 if kind == "folder" and r.exit_code == 2 else 1, target)
        assert os.path.lexists(target) and (target.is_symlink() or not target.is_file()), name
        assert sorted(p.name for p in target.parent.iterdir()) == sorted([name] + (["target"] if kind == "symlink"
                                                                                   else [])), name
        shutil.rmtree(target.parent)


# --- Injection into pages ------------------------------------------------------------------------

PAYLOADS = ["</title><script>document.body.setAttribute('data-pwned','1')</script>",
            "<img src=x onerror=\"document.body.setAttribute('data-pwned','1')\">", "-->", "<!--", "</script>",
            "__DATA__", "__TITLE__", "__W__", "$\\bad$", "\\nosuchmacro", "$x^2$", "![x](/etc/hostname)",
            "&amp;", "\u2028", "'\"", "{{x}}", "|", "`code`"]
HOSTILE_NAME = st.lists(st.sampled_from(PAYLOADS), min_size=1, max_size=4).map(" ".join)


def scene_named(name, tmp):
    from deepcontact.scene.generators import generate
    from deepcontact.scene.xml import to_xml
    from xml.sax.saxutils import quoteattr
    text = to_xml(generate("pile", 0, {"count": "6", "box": "8", "sigma": "1.5"})).decode()
    text = re.sub(r'<scene name="[^"]*"', lambda m: f"<scene name={quoteattr(name)}", text, count=1)
    path = tmp / "scene.xml"
    path.write_text(text)
    return path


def scripts_of(page):
    tree = lxml_html.fromstring(page.read_bytes())
    return tree, [s.get("id") for s in tree.iter("script")]


@pytest.fixture(scope="module")
def loop_rows(tmp_path_factory):
    """The closed loop's rows of a small pile, stepped once: what a loop report is written from
    (the contestants that stepped it are not what the names below test; `dc evaluate --closed-loop`
    with a hostile name runs whole in the browser test)."""
    from deepcontact import closed_loop, make_starts
    from deepcontact.scene.xml import read_scene
    return closed_loop(read_scene(scene_named("pile", tmp_path_factory.mktemp("loop"))), make_starts(["builtin"]),
                       steps=10)


@SETTINGS
@given(name=HOSTILE_NAME)
def test_a_hostile_scene_name_is_text_in_every_page_and_picture(tmp_path_factory, loop_rows, name):
    from deepcontact.evaluate.loop_report import write_loop_report
    from deepcontact.solver.settings import SolveSettings
    tmp = tmp_path_factory.mktemp("inject")
    scene = scene_named(name, tmp)
    r = invoke("simulate", scene, "--steps", "40", "-q", "-o", tmp / "run")
    assert r.exit_code == 0, r.stderr
    page = tmp / "view.html"
    assert invoke("render", tmp / "run", "--every", "10", "-q", "-o", page).exit_code == 0
    tree, scripts = scripts_of(page)
    assert scripts == ["data", None]                       # the viewer's own two, nothing else
    assert name in tree.findtext(".//title")
    assert json.loads(tree.get_element_by_id("data").text)["scene"] == name
    assert not list(tree.iter("img"))
    r = invoke("render", tmp / "run" / "seed-000000" / "step-000039.xml", "-q", "-o", tmp / "s.png")
    assert r.exit_code == 0, r.stderr                      # mathtext off: the name is drawn as written
    (tmp / "loop").mkdir()   # (the closed loop's report, as dc evaluate names it: the scene, its runs)
    write_loop_report(tmp / "loop", loop_rows, f"{name}, 1 simulation of {tmp / 'run'}", SolveSettings())
    tree, scripts = scripts_of(tmp / "loop" / "report.html")
    assert scripts == [] and name in tree.findtext(".//title")
    assert len(list(tree.iter("img"))) + len(list(tree.iter("svg"))) == 1   # the one plot it drew


def test_only_pictures_the_command_drew_are_inlined(tmp_path):
    from deepcontact.html import markdown_to_html
    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG secret")
    evil = tmp_path / "plot.svg"
    evil.write_text('<svg xmlns="http://www.w3.org/2000/svg"><script>alert(1)</script></svg>')
    (tmp_path / "plot.png").write_bytes(b"\x89PNG")
    page = markdown_to_html(f"# t\n\n![s]({secret})\n\n![s](secret.png)\n\n![p](plot.png)\n", tmp_path, "t",
                            pictures=("plot.png",))
    tree = lxml_html.fromstring(page)
    assert not list(tree.iter("script")) and "c2VjcmV0" not in page     # (base64 of 'secret')
    srcs = [img.get("src") for img in tree.iter("img")]
    assert len(srcs) == 1 and srcs[0].startswith("data:image/svg+xml;base64,")   # the SVG, inert in an <img>


@needs_browser[0]
@needs_browser[1]
def test_no_injected_script_runs_in_a_real_browser(tmp_path):
    name = " ".join(PAYLOADS[:3])
    scene = scene_named(name, tmp_path)
    assert invoke("simulate", scene, "--steps", "30", "-q", "-o", tmp_path / "run").exit_code == 0
    assert invoke("render", tmp_path / "run", "--every", "10", "-q", "-o", tmp_path / "v.html").exit_code == 0
    r = invoke("evaluate", tmp_path / "run", "--starts", "builtin", "--closed-loop", "--steps", "10", "--no-budgets",
               "-q", "-o", tmp_path / "loop")
    assert r.exit_code == 0, r.stderr
    for page in (tmp_path / "v.html", tmp_path / "loop" / "report.html"):
        dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=2000",
                              "--dump-dom", page.resolve().as_uri()], capture_output=True, text=True, timeout=120,
                             check=True).stdout
        body = re.search(r"<body[^>]*>", dom).group()
        assert "data-pwned" not in body, body
        assert "</body>" in dom and len(dom) > 1000   # the page loaded and was read whole


# --- No traceback: checkpoints, metadata, manifolds, non-finite worlds, deep trees ----------------

CHECKPOINT_KEYS = ["epoch", "best", "bad_epochs", "history", "dataset.grid.cell", "dataset.grid.nx",
                   "dataset.grid.x0", "dataset.grid.kernel", "dataset.inputs", "targets", "train_config.lr",
                   "train_config.batch_size"]
HOSTILE_VALUES = [None, "abc", -1, float("nan"), float("inf"), [], {}, [1, "a"], 2 ** 40, True, 1e300, -1e300]


@SETTINGS
@given(key=st.sampled_from(CHECKPOINT_KEYS), value=st.sampled_from(HOSTILE_VALUES))
def test_a_tampered_checkpoints_bookkeeping_is_one_line(model, dataset, tmp_path_factory, key, value):
    tmp = tmp_path_factory.mktemp("ck")
    ck = torch.load(model / "last.pt", weights_only=True)
    *parents, last = key.split(".")
    d = ck
    for p in parents:
        d = d[p]
    d[last] = value
    torch.save(ck, tmp / "last.pt")
    r = invoke("evaluate", "--no-plots", dataset.parent / "run", "--starts", "cnn", "--checkpoint", tmp / "last.pt",
               "--every", "60", "--no-budgets", "-q", "-o", tmp / "r")
    assert_clean(r, tmp / "r")
    shutil.copytree(model, tmp / "m")
    shutil.copy(tmp / "last.pt", tmp / "m" / "last.pt")
    before = snapshot(tmp / "m")
    r = invoke("train", dataset, "-o", tmp / "m", "--resume", "--epochs", "2", "-q")
    assert_clean(r, None)
    if r.exit_code:
        assert snapshot(tmp / "m") == before


@SETTINGS
@given(key=st.sampled_from(["x0", "y0", "cell", "h", "nx", "ny", "kernel", "renormalize", "extra"]),
       value=st.sampled_from(HOSTILE_VALUES + ["0.5"]))
def test_tampered_grid_metadata_is_one_line(dataset, tmp_path_factory, key, value):
    tmp = tmp_path_factory.mktemp("meta")
    data = shutil.copytree(dataset, tmp / "data")
    meta = json.loads((data / "metadata.json").read_text())
    meta["grid"][key] = value
    (data / "metadata.json").write_text(json.dumps(meta))
    for args in (["train", data, "--epochs", "1", "--width", "4", "--depth", "2", "--no-plots", "-q", "-o", tmp / "m"],
                 ["render", data, "--sample", "0", "-q", "-o", tmp / "p.png"]):
        r = invoke(*args)
        assert_clean(r, tmp / "m")
        if r.exit_code == 1:
            assert "metadata.json" in r.stderr, r.stderr


def manifold_rows(step):
    """The line spans of each <contact> element of a step file."""
    lines = step.read_text().splitlines(keepends=True)
    starts = [i for i, line in enumerate(lines) if line.lstrip().startswith("<contact ")]
    spans = []
    for i in starts:
        j = i
        while "</contact>" not in lines[j]:
            j += 1
        spans.append((i, j + 1))
    return lines, spans


@pytest.fixture(scope="session")
def boxes_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("boxes") / "run"
    scenes = Path(__file__).parent.parent / "datasets" / "scenes"
    assert invoke("simulate", scenes / "boxes-and-circles.xml", "--steps", "40", "-q", "-o", out).exit_code == 0
    return out


@SETTINGS
@given(data=st.data())
def test_manifold_points_out_of_order_are_one_line(boxes_run, tmp_path_factory, data):
    tmp = tmp_path_factory.mktemp("manifold")
    run = shutil.copytree(boxes_run, tmp / "run")
    step = sorted(run.glob("seed-000000/step-*.xml"))[-1]
    lines, spans = manifold_rows(step)
    order = data.draw(st.permutations(range(len(spans))))
    if list(order) == sorted(order):
        return
    body = "".join("".join(lines[a:b]) for a, b in (spans[k] for k in order))
    step.write_text("".join(lines[:spans[0][0]]) + body + "".join(lines[spans[-1][1]:]))
    for args in (["validate", run], ["evaluate", "--no-plots", run, "--starts", "builtin", "-q", "-o", tmp / "r"],
                 ["export", run, "-q", "-o", tmp / "x"]):
        r = invoke(*args)
        assert_clean(r, None)


def test_a_simulation_that_leaves_float32_is_one_line(tmp_path):
    r = invoke("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5", "--steps",
               "30", "--solver", "pgs", "--start", "garbage", "--mode", "exact", "--max-iterations", "1", "-q",
               "-o", tmp_path / "run")
    assert_clean(r, tmp_path / "run")


def test_a_solve_whose_residual_is_not_a_number_is_one_line_and_publishes_nothing(tmp_path):
    # exact mode uses a start as given: garbage (1e30, NaN) leaves the solver's velocities NaN while
    # its clamped answer stays finite; the residual read 0 there, and the step files said so
    r = invoke("simulate", "pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps",
               "120", "--solver", "pgs", "--start", "garbage", "--mode", "exact", "-q", "-o", tmp_path / "run")
    assert_clean(r, tmp_path / "run")
    assert "without a finite residual (exact mode, 8 sweeps)" in r.stderr, r.stderr


def test_a_residual_that_is_not_a_number_names_its_seed(tmp_path):
    # one seed of several: the line said "step 11" and not whose
    r = invoke("simulate", "pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps",
               "120", "--seeds", "4..5", "--solver", "pgs", "--start", "garbage", "--mode", "exact", "-q", "-o",
               tmp_path / "run")
    assert_clean(r, tmp_path / "run")
    assert re.search(r"seed [45], step \d+: the project's solver ended without a finite residual", r.stderr), r.stderr


def test_only_the_projects_solver_is_held_to_a_finite_residual(tmp_path):
    # another engine's step has no residual of ours to judge: the check read its solution field
    # (an engine of one's own, in this process, handing its deepest penetration third, where
    # LoopStep keeps the project's solution), an AttributeError and a traceback
    import deepcontact as dc

    class DeepestThird(dc.Box2D):
        def stepper(self, world, scene, record=True):
            step = super().stepper(world, scene, record)
            return lambda: (lambda done: dc.LoopStep(done.bodies, done.contacts, done.deepest,
                                                     dt_ratio=done.dt_ratio))(step())

    dc.simulate_run(dc.SceneSource("pile", {"count": "6", "box": "8", "sigma": "2"}, steps=3), [0], tmp_path / "run",
                    engine=DeepestThird())
    assert len(list((tmp_path / "run").glob("seed-000000/step-*.xml"))) == 3


def test_a_deep_tree_is_walked_without_recursion(tmp_path):
    d = tmp_path
    for _ in range(1200):   # deeper than Python's recursion limit (os.makedirs itself recurses)
        d = d / "d"
        os.mkdir(d)
    (d / "x.xml").write_text("<step/>")
    try:
        r = invoke("validate", tmp_path)
        assert r.exit_code == 1 and "Traceback" not in r.stderr and "1 file checked" in r.stderr, r.stderr
    finally:   # from the bottom up: shutil.rmtree (and pytest's clean-up) recurse
        (d / "x.xml").unlink()
        while d != tmp_path:
            d.rmdir()
            d = d.parent


# --- Silently wrong output ---------------------------------------------------------------------

RESUME_OPTIONS = [("--width", "8"), ("--depth", "3"), ("--loss", "mse"), ("--optimizer", "adam"), ("--lr", "0.01"),
                  ("--batch-size", "7"), ("--seed", "3"), ("--targets", "normal_impulse"), ("--arch", "thesis"),
                  ("--threads", "2")]


@pytest.mark.parametrize("option,value", RESUME_OPTIONS)
def test_resume_refuses_other_settings(model, dataset, tmp_path, option, value):
    out = shutil.copytree(model, tmp_path / "m")
    before = snapshot(out)
    r = invoke("train", dataset, "-o", out, "--resume", "--epochs", "2", option, value, "-q")
    assert r.exit_code == 2 and "Traceback" not in r.stderr, r.stderr
    assert snapshot(out) == before


def test_resume_refuses_another_dataset(run, model, tmp_path):
    other = tmp_path / "other"
    assert invoke("rasterize", run, "--cell", "1", "--smoothing", "1", "--validation", "0.5", "--seed", "5",
                  "--include-contactless", "-q", "-o", other).exit_code == 0
    out = shutil.copytree(model, tmp_path / "m")
    r = invoke("train", other, "-o", out, "--resume", "--epochs", "2", "-q")
    one_line(r, 1, "another dataset")


def test_a_copied_run_edited_scene_copied_step_and_zeroed_count_are_refused(run, tmp_path):
    copied = shutil.copytree(run, tmp_path / "copy")
    one_line(invoke("rasterize", run, copied, "--cell", "1", "--smoothing", "1", "-o", tmp_path / "d1"), 1,
             "the same simulation twice")
    edited = shutil.copytree(run, tmp_path / "edited")
    with open(edited / "seed-000000" / "scene.xml", "a") as f:
        f.write("\n")
    one_line(invoke("rasterize", edited, "--cell", "1", "--smoothing", "1", "-o", tmp_path / "d2"), 1,
             "changed since the run")
    one_line(invoke("evaluate", "--no-plots", edited, "--closed-loop", "--starts", "builtin", "--steps", "5", "-o",
                    tmp_path / "e"),
             1, "changed since the run")
    manifest = json.loads((run / "manifest.json").read_text())
    counts = manifest["simulations"][0]["file_contact_points"]
    k = max(i for i, n in enumerate(counts) if n)
    moved = shutil.copytree(run, tmp_path / "moved")
    shutil.copy(moved / "seed-000000" / f"step-{k:06d}.xml", moved / "seed-000000" / f"step-{k - 1:06d}.xml")
    err = one_line(invoke("rasterize", moved, "--cell", "1", "--smoothing", "1", "-o", tmp_path / "d3"), 1)
    assert f"step-{k - 1:06d}.xml" in err
    zeroed = shutil.copytree(run, tmp_path / "zeroed")
    m = json.loads((zeroed / "manifest.json").read_text())
    m["simulations"][0]["file_contact_points"][k] = 0
    (zeroed / "manifest.json").write_text(json.dumps(m))
    one_line(invoke("rasterize", zeroed, "--cell", "1", "--smoothing", "1", "-o", tmp_path / "d4"), 1,
             "the manifest recorded 0")


@pytest.mark.parametrize("value", ["-0.5", "-1e-9", "nan"])
def test_export_refuses_what_validate_refuses(run, tmp_path, value):
    bad = shutil.copytree(run, tmp_path / "run")
    step = sorted(bad.glob("seed-000000/step-*.xml"))[-1]
    text = step.read_text()
    assert ' friction="' in text
    step.write_text(re.sub(r' friction="[^"]*"', f' friction="{value}"', text))
    assert invoke("validate", bad).exit_code == 1
    r = invoke("export", bad, "-q", "-o", tmp_path / "x")
    one_line(r, 1, step.name)
    assert not (tmp_path / "x").exists()


def test_render_refuses_a_model_of_another_grid(run, dataset, model, tmp_path):
    other = tmp_path / "other"
    assert invoke("rasterize", run, "--cell", "0.5", "--smoothing", "0.5", "-q", "-o", other).exit_code == 0
    one_line(invoke("render", other, "--sample", "0", "--checkpoint", model / "best.pt", "-o", tmp_path / "p.png"), 1,
             "another grid")
    assert not (tmp_path / "p.png").exists()


def test_training_is_the_same_on_any_machine_by_default(dataset, tmp_path):
    args = ["--epochs", "1", "--width", "4", "--depth", "2", "-q"]
    assert invoke("train", "--no-plots", dataset, "-o", tmp_path / "a", *args).exit_code == 0
    torch.set_num_threads(2)      # a machine with other defaults: the command's default still holds
    assert invoke("train", "--no-plots", dataset, "-o", tmp_path / "b", *args).exit_code == 0
    a = torch.load(tmp_path / "a" / "last.pt", weights_only=True)
    b = torch.load(tmp_path / "b" / "last.pt", weights_only=True)
    assert a["threads"] == b["threads"] == 1
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])


def test_a_killed_movie_or_picture_leaves_nothing_the_next_run_keeps(run, tmp_path):
    out = tmp_path / "movie.gif"
    script = f"""
import os, signal
from deepcontact import output
from deepcontact.render import frames
real = frames._gif_frame
def killed(data, first):
    if not first:
        os.kill(os.getpid(), signal.SIGKILL)
    return real(data, first)
frames._gif_frame = killed
from deepcontact.cli.main import cli
cli(["render", {str(run)!r}, "--every", "20", "-q", "-o", {str(out)!r}], standalone_mode=False)
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert r.returncode == -signal.SIGKILL, r.stderr
    left = sorted(p.name for p in tmp_path.iterdir())
    assert any(n.endswith(".tmp") for n in left) and not out.exists(), left
    assert invoke("render", run, "--every", "20", "-q", "-o", out).exit_code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["movie.gif"]


# --- Memory, hangs and late refusals -----------------------------------------------------------

@pytest.mark.parametrize("megabytes", [1, 40])
def test_a_compressed_bomb_is_refused_early(tmp_path, megabytes):
    body = b'<step format="1">' + b"<a/>" * (megabytes << 18) + b"</step>"
    bomb = tmp_path / "step-000000.xml.gz"
    bomb.write_bytes(gzip.compress(body, 9))
    r = invoke("validate", bomb)
    assert r.exit_code == 1 and "Traceback" not in r.stderr
    if len(body) > 64 * bomb.stat().st_size and len(body) > 16 << 20:
        assert "64 times its compressed size" in r.stdout + r.stderr, r.stdout


def test_the_gif_writer_holds_one_frame(tmp_path):
    from deepcontact.render.frames import gif_chunk, write_gif
    sizes = []
    out = tmp_path / "a.gif"

    rng = np.random.default_rng(0)
    shown = []

    def frames():
        for k in range(6):
            partial = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
            sizes.append(partial[0].stat().st_size if partial else 0)
            shown.append(rng.integers(0, 4, (96, 128, 1), dtype=np.uint8).repeat(3, axis=2) * 60)   # (noise: >8 kB)
            yield shown[-1]
    assert write_gif(out, (gif_chunk(rgb, 10, first=k == 0) for k, rgb in enumerate(frames()))) == 6
    assert all(b > a for a, b in zip(sizes[1:], sizes[2:]))   # each frame written before the next is drawn
    from PIL import Image
    im = Image.open(out)
    assert im.n_frames == 6 and im.size == (128, 96)
    for k in (0, 5):
        im.seek(k)
        assert np.array_equal(np.asarray(im.convert("RGB")), shown[k])   # 4 grey levels: exact in 128 colours


def test_estimates_come_before_the_work(run, dataset, tmp_path):
    one_line(invoke("evaluate", "--no-plots", run, "--starts", "zero,builtin", "--max-iterations", "100000000", "-o",
                    tmp_path / "r"),
             1, "convergence histories", "--max-memory")
    assert not (tmp_path / "r").exists()
    r = invoke("train", dataset, "--loss", "solver", "--solver-sweeps", "5", "--max-memory", "0.000001",
               "--epochs", "1", "--width", "4", "--depth", "2", "-o", tmp_path / "m")
    one_line(r, 1, "solver loss")
    (tmp_path / "a-file").write_text("in the way")   # (a missing folder is made: a file cannot be)
    r = invoke("study", "stability", "--fast", "-o", tmp_path / "a-file" / "folder" / "t.md")
    one_line(r, 1, "cannot write there")
    assert "configurations" not in r.stdout     # refused before the study, not after it
    r = invoke("render", run, "--window", "0,0,0.00001,0.00001", "-o", tmp_path / "w.gif")
    assert r.exit_code == 2 and "--window" in r.stderr


def test_the_disk_estimate_counts_fixtures(tmp_path):
    from deepcontact.resources import step_bytes
    assert step_bytes(101, 101) == pytest.approx(160e3, rel=0.2)   # the thesis pile's measured step file
    assert step_bytes(10, 400) > 20 * step_bytes(10, 10)


# --- Messages and exit codes ------------------------------------------------------------------

def test_option_errors_exit_2_and_files_that_are_not_checkpoints_say_so(run, tmp_path):
    for args in (["evaluate", run, "--starts", "builtin,cnn", "-o", tmp_path / "r"],
                 ["rasterize", run, "--cell", "1e-300", "-o", tmp_path / "d"],
                 ["evaluate", run, "--starts", "sph", "--smoothing", "1e-300", "-o", tmp_path / "r"]):
        r = invoke(*args)
        assert r.exit_code == 2 and "Traceback" not in r.stderr, r.stderr
    png = tmp_path / "picture.png"
    assert invoke("render", sorted(run.glob("seed-000000/step-*.xml"))[-1], "-q", "-o", png).exit_code == 0
    for bogus in (png, tmp_path / "notes.txt"):
        bogus.exists() or bogus.write_text("not a checkpoint")
        err = one_line(invoke("evaluate", run, "--starts", "cnn", "--checkpoint", bogus, "-o", tmp_path / "r"), 1)
        assert "not a checkpoint" in err and "run code" not in err and "weights_only" not in err, err


def _die_on_two(task):
    if task == 2:
        os.kill(os.getpid(), signal.SIGKILL)   # the worker killed (the OOM killer, a user)
    return task


def _die_always(args):
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_killed_worker_is_one_line_and_the_output_is_not_kept(run, tmp_path, monkeypatch):
    from deepcontact import workers
    from deepcontact.errors import Failure
    with pytest.raises(Failure, match="worker process died"):
        with workers.pool(2) as pool:
            list(pool.imap(_die_on_two, range(6)))
    # through a command: a rasterizing worker killed midway
    from deepcontact.grid import dataset as D
    monkeypatch.setattr(D, "_rasterize_steps", _die_always)
    r = invoke("rasterize", run, "--cell", "1", "--smoothing", "1", "-j", "2", "-o", tmp_path / "d")
    one_line(r, 1, "worker process died")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
