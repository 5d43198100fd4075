"""`dc study`: the longer measurements as subcommands, with the same output rules as the rest."""
import sys

import pytest

from conftest import dc, one_line_error
from dcstudies.efforts import EFFORTS

# (run and dataset: the session's small pile and its grids, tests/conftest.py)


def test_dc_study_lists_the_studies():
    r = dc("study", "--help")
    assert r.returncode == 0 and "Examples:" in r.stdout
    for name in ("stability", "engines", "frontier", "figures", "exact", "peer", "scale"):
        assert name in r.stdout
        assert "Examples:" in dc("study", name, "--help").stdout


def test_the_fast_stability_table_is_written_and_not_overwritten_unasked(tmp_path):
    # (two of the fast cases, by --scenes: the study runs fenced, in a process of its own;
    # tests/test_stability.py runs the whole fast study, once)
    out = tmp_path / "stability.md"
    r = dc("study", "stability", "--fast", "--scenes", "stack 8,bullet", "-j", "2", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    table = out.read_text()
    assert table.startswith("# Stability of the hard scenes: fast") and "Measured with 1 torch thread" in table \
        and "\n| scene | solver |" in table and "| stack" in table and "| bullet |" in table
    assert {line.split("|")[1].strip() for line in table.splitlines()[1:] if line.startswith("| ")} - \
        {"scene", "---"} == {"stack 8", "bullet"}
    one_line_error(dc("study", "stability", "--fast", "-o", str(out)), out, "--overwrite")


# (dc study figures: tests/test_jobs.py, its files with -j 1 and -j 2)


def test_dc_study_is_built_from_the_registry_of_studies():
    """Every `dc study` command is a study registered in deepcontact.studies.STUDIES (the studies
    distribution's entry points), in the studies' order, and its -o what the study says it writes;
    a study registered in code is a command too, with no change to `dc study`."""
    from click.testing import CliRunner
    from deepcontact.cli.study import study
    from deepcontact.studies import STUDIES, Study, command_of, installed
    studies = installed()
    assert [s.name for s in studies] == study.list_commands(None)
    assert [s.name for s in studies][:3] == ["stability", "engines", "frontier"]
    helped = CliRunner().invoke(study, ["--help"]).output
    for row in studies:
        assert issubclass(row, Study) and row.name in helped and row.summary.split()[0] in helped
        command = command_of(row.name)   # (dc study runs it fenced: tests/test_study_fence.py)
        (out,) = [p for p in command.params if "-o" in getattr(p, "opts", ())]
        assert row.writes in ("folder", "file", "text")
        folder = row.writes == "folder"
        assert (out.type.dir_okay, out.type.file_okay) == (folder, not folder), row
    import click

    @click.command("hello")
    def hello():
        """Says hello."""
        click.echo("hello, study")

    class Hello(Study):
        name, summary, order = "hello", "a study of one's own", 0.5
        command = staticmethod(lambda: hello)
    STUDIES.register("hello", Hello)
    try:
        assert study.list_commands(None)[1] == "hello"
        assert CliRunner().invoke(study, ["hello"]).output == "hello, study\n"
    finally:
        del STUDIES._builtin["hello"]


def test_every_study_module_imports_and_the_exact_study_runs():
    import importlib
    import pkgutil
    import dcstudies
    for info in pkgutil.iter_modules(dcstudies.__path__):
        importlib.import_module(f"dcstudies.{info.name}")
    r = dc("study", "exact", "--scene", "pile", "--every", "150")
    assert r.returncode == 0, r.stderr
    assert "Measured with" in r.stdout and "| reference: Newton, then local pivots where it stalls |" in r.stdout
    assert dc("study", "exact", "--scene", "hard", "--siconos").returncode == 2


def test_the_scale_study_runs_as_a_dc_study_command(tmp_path):
    """The scaling table (once a benchmark script, now a study) at toy size: a settled 100-circle
    pile, one step, PSOR, from zero and from Box2D's warm start; with -o FILE its report is also
    written there, as every text study's is."""
    r = dc("study", "scale", "--quick", "--samples", "1", "--sizes", "100", "--methods", "PSOR 1.7", "-q")
    assert r.returncode == 0, r.stderr
    assert "Measured with" in r.stdout and r.stdout.count("| PSOR 1.7 | ") == 2 and "From zero" in r.stdout
    # -o FILE: the same report, written once the study ends; never replaced unasked
    report = tmp_path / "scale.md"
    r = dc("study", "scale", "--quick", "--samples", "1", "--sizes", "100", "--methods", "PSOR 1.7", "-q",
           "-o", report)
    assert r.returncode == 0, r.stderr
    assert report.read_text() == r.stdout and r.stdout.count("| PSOR 1.7 | ") == 2
    r = dc("study", "scale", "--quick", "--samples", "1", "--sizes", "100", "-q", "-o", report)
    assert r.returncode == 1 and "--overwrite" in r.stderr and str(report) in r.stderr
    r = dc("study", "scale", "--methods", "Nope")
    assert r.returncode == 2 and "no method 'Nope'" in r.stderr


def test_a_study_runs_a_setting_with_its_method_and_relaxation():
    """engines.run_setting is what both scale studies run a setting with: the setting's method and
    w reach the run (the engines study once ran its lagged family with plain sweeps and timed it
    with the lagged solve). On an 8-box stack at 8 sweeps to 1e-8 the sweeps stop at the cap on
    every step, the lagged solve on few."""
    from dcstudies import engines as E, stability as S
    stack = next(c for c in S.FAST if c.label == "stack 8")
    plain, lagged, relaxed = (E.run_setting(stack, E.Setting("project", "residual 1e-08", "pgs", 8, tolerance=1e-8,
                                                             relaxation=w, accelerate=m))
                              for m, w in (("none", 1.0), ("lagged", 1.0), ("none", 1.7)))
    assert (plain.start, lagged.start, relaxed.start) == ("builtin", "builtin+lagged", "builtin@1.7")
    assert plain.capped == 240 and lagged.capped < 24


def test_the_frontier_study_judges_every_setting_by_one_residual(tmp_path):
    """The fast frontier (a 30-circle pile, a base-5 pyramid): its tables and plots are written,
    and what it measures holds together: Box2D's 8 iterations, replayed bit for bit, and the
    project's 8 float64 sweeps from the same warm start reach the same one-step residual to float32
    rounding; a project setting that stopped below its tolerance on every timed step has a one-step
    residual below it too; v3 has none; every engine setting gets a line in the summary."""
    import csv
    out = tmp_path / "frontier"
    r = dc("study", "frontier", "--fast", "-q", "-o", out)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader((out / "frontier.csv").open()))
    assert {row["scene"] for row in rows} == {"pile 30", "pyramid 5"}
    for scene in ("pile 30", "pyramid 5"):
        mine = {(row["family"], row["setting"]): row for row in rows if row["scene"] == scene}
        box2d, ours = (float(mine[k]["residual_median"]) for k in (("Box2D 2.4.1", "8 iterations"),
                                                                     ("PGS", "8 sweeps")))
        assert box2d == pytest.approx(ours, rel=1e-2, abs=1e-5), scene   # (float32 rounding near 0)
        for (family, setting), row in mine.items():
            if family == "Box2D v3":
                assert row["residual_median"] == "nan"
            elif setting.startswith("residual"):
                assert float(row["residual_max"]) < float(setting.split()[1])
            assert float(row["ms_per_step"]) > 0
    text = (out / "frontier.md").read_text()
    engine_rows = sum(row["family"] in ("Box2D 2.4.1", "Box2D v3") for row in rows)
    summary = text.split("## For each engine setting")[1].split("\n## ")[0]
    assert summary.count("\n| pile 30 | Box2D") + summary.count("\n| pyramid 5 | Box2D") == engine_rows
    assert (out / "frontier-pile-30.png").stat().st_size > 0 and (out / "frontier-pyramid-5.png").stat().st_size > 0
    assert (out / "frontier-pile-30-penetration.png").stat().st_size > 0   # (every engine: pymunk's, MuJoCo's)
    equal = text.split("## At equal time")[1].split("\n## ")[0]
    assert equal.count("\n| pile 30 | ") == sum(row["scene"] == "pile 30" and row["family"] == "Box2D 2.4.1" for row in rows)
    r = dc("study", "frontier", "--scenes", "pile 7", "-o", tmp_path / "none")
    assert r.returncode == 2 and "no scene 'pile 7'" in r.stderr


def test_at_equal_time_the_best_residual_within_the_engines_time_is_named():
    """For each Box2D 2.4.1 setting, the project setting with the smallest residual among those no
    slower: a faster but less accurate one loses to a slower, more accurate one that still fits; one
    over the time never counts; a cap does not disqualify (at equal time the residual reached counts)."""
    from dcstudies import frontier as F

    def row(family, setting, ms, residual, capped=None):
        return F.Row(scene="s", family=family, setting=setting, passed=True, finite=True, ms_per_step=ms,
                     residual_median=residual, residual_max=residual, velocity_error=float("nan"), penetration=0.0,
                     energy_rise=0.0, energy_allowed=1.0, capped=capped, samples=4)
    box2d = [row("Box2D 2.4.1", "1 iteration", 1.0, 0.5), row("Box2D 2.4.1", "8 iterations", 2.0, 0.1)]
    ours = [row("PGS", "4 sweeps", 0.9, 0.4), row("PSOR 1.7", "8 sweeps", 1.9, 0.05),
            row("NNCG", "residual 0.0001", 5.0, 1e-4, capped=3), row("Box2D v3", "4 substeps", 0.1, float("nan"))]
    got = {e.setting: (p.family if p else None) for e, p in F.at_equal_time(box2d + ours)}
    assert got == {"1 iteration": "PGS", "8 iterations": "PSOR 1.7"}
    assert F.at_equal_time([row("Box2D 2.4.1", "1 iteration", 0.5, 0.5)] + ours)[0][1] is None
    table = F.equal_time_table(box2d + ours)
    assert "| s | 8 iterations | 2 | 0.1 | PSOR 1.7, 8 sweeps | 1.9 | 0.05 | 0.5x |" in table


def test_the_frontier_study_runs_the_part_asked_for(tmp_path):
    """--families and --tolerances pick settings (what the largest scenes' rows were measured
    with); a family it does not have is a bad option, listing the ones it has."""
    import csv
    from dcstudies import frontier as F
    picked = F.settings(families=("NNCG", "Box2D v3"), tolerances=(1e-3,))
    assert [(s.family, s.label) for s in picked] == [("Box2D v3", f"{n} substeps") for n in EFFORTS["box2d3"].sweep] + \
        [("NNCG", "residual 0.001")]
    out = tmp_path / "part"
    r = dc("study", "frontier", "--fast", "-q", "--scenes", "pyramid 5", "--families", "Box2D 2.4.1,PSOR 1.7",
           "--tolerances", "1e-3", "-o", out)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader((out / "frontier.csv").open()))
    assert [(row["family"], row["setting"]) for row in rows] == \
        [("Box2D 2.4.1", f"{n} iterations") for n in (1, 8, 64)] + [("PSOR 1.7", "8 sweeps"), ("PSOR 1.7", "residual 0.001")]
    r = dc("study", "frontier", "--fast", "--families", "PGS,Jacobi", "-o", tmp_path / "none")
    assert r.returncode == 2 and "no family 'Jacobi'" in r.stderr and "lagged" in r.stderr
    # one setting of a family: FAMILY:SETTING, as the tables name it
    one = F.settings(families=("pymunk:10 iterations", "MuJoCo Newton:tolerance 1e-08", "PGS"), tolerances=(1e-2,))
    assert [(s.family, s.label) for s in one] == [("pymunk", "10 iterations"), ("MuJoCo Newton", "tolerance 1e-08")] + \
        [("PGS", f"{n} sweeps") for n in F.BUDGETS] + [("PGS", "residual 0.01")]
    # with only an engine's family asked for, the summary says the project's were not run (not "none")
    only = tmp_path / "only-box2d"
    r = dc("study", "frontier", "--fast", "-q", "--scenes", "pyramid 5", "--families", "Box2D 2.4.1:1 iterations",
           "-o", only)
    assert r.returncode == 0, r.stderr
    line = next(x for x in (only / "frontier.md").read_text().splitlines() if x.startswith("| pyramid 5 | Box2D"))
    assert "| not run (no project family asked) |" in line and "| none |" not in line, line
    r = dc("study", "frontier", "--fast", "--families", "pymunk:11 iterations", "-o", tmp_path / "none")
    assert r.returncode == 2 and "'11 iterations'" in r.stderr and "10 iterations" in r.stderr
    assert not (tmp_path / "none").exists()


BROKEN = {   # module file -> its text; each an installed study of the distribution dc-broken
    "dc_broken_raises.py": "raise RuntimeError('broken at import')\n",
    "dc_broken_not.py": "class S:\n    pass\n",
    "dc_broken_cmd.py": "from deepcontact.studies import Study\nclass S(Study):\n    name = 'badcommand'\n"
                        "    @staticmethod\n    def command():\n        raise ValueError('no command here')\n",
}


def test_a_broken_study_is_one_line_and_hides_no_other(tmp_path, monkeypatch):
    """An installed distribution whose study entry point names a missing module, raises on
    import, is not a Study, or whose command() raises: every healthy study is still listed and
    runs; each broken one is a line naming its distribution and entry point, in --help and when run."""
    info = tmp_path / "dc_broken-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dc-broken\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[deepcontact.studies]\nmissing = dc_broken_nosuch:Study\n"
                                           "raises = dc_broken_raises:S\nnotastudy = dc_broken_not:S\n"
                                           "badcommand = dc_broken_cmd:S\n")
    for name, text in BROKEN.items():
        (tmp_path / name).write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    from deepcontact.studies import STUDIES
    try:
        r = dc("study", "--help")
        assert r.returncode == 0, r.stderr
        listed, broken = r.stdout.split("Broken")
        for name in ("stability", "engines", "frontier", "figures", "exact", "peer", "scale"):
            assert name in listed
        flat = " ".join(broken.split())
        for name, why in (("missing", "No module named 'dc_broken_nosuch'"), ("raises", "broken at import"),
                          ("notastudy", "is not a deepcontact.studies.Study"), ("badcommand", "no command here")):
            assert f"the study '{name}' (dc-broken 1.0, entry point {name} = " in flat and why in flat, flat
            one_line_error(dc("study", name), f"the study '{name}'", "dc-broken 1.0", why)
        assert "Examples:" in dc("study", "exact", "--help").stdout
    finally:
        STUDIES._loaded = {k: v for k, v in STUDIES._loaded.items() if k not in ("raises", "notastudy", "badcommand")}
        for name in BROKEN:
            sys.modules.pop(name[:-3], None)


def test_a_project_study_without_its_distribution_says_how_to_get_it(monkeypatch):
    """Without the studies distribution, `dc study stability` was click's "No such command"."""
    from deepcontact.studies import STUDIES
    monkeypatch.setattr(STUDIES, "installed", lambda: {})
    one_line_error(dc("study", "stability", "--fast"), "the study 'stability'", "pip install ./studies")
    assert dc("study", "nonesuch").returncode == 2   # (a study nobody makes: click's usage error)
