"""The studies' `dc study` commands: one click command and one Study each (what `dc study` lists,
through the `deepcontact.studies` entry points of this distribution's pyproject.toml)."""
import contextlib

import click

from deepcontact import output as outputs
from deepcontact.cli import options, terminal, types
from deepcontact.studies import Study, units


def text_report(f):
    """What a study that reports in text takes: --threads, and -o FILE with --overwrite (its report
    also written to FILE, atomically, once the study ends; checked and locked before it starts)."""
    f = options.overwrite(f)
    f = click.option("-o", "--output", "output", type=click.Path(dir_okay=False),
                     help="Also write the report to this file (once the study ends).")(f)
    return options.threads(f)


def resumable(f):
    """What a study that keeps its finished units of work takes: --resume (deepcontact.studies.units)."""
    return click.option("--resume", is_flag=True, help="Reuse the finished units of work (a setting on a scene) that a "
                        "stopped run kept beside the same output, where measured with the same options, and measure "
                        "the rest. A run refuses to start over such units without it (--overwrite: measure all "
                        "again).")(f)


def keeping(study, resume, overwrite, jobs):
    """The study's finished units kept beside its output (units.keeping), keyed by this
    distribution's code as well as deepcontact's, and by the worker processes (-j) that time them."""
    import dcstudies
    return units.keeping(f"study {study}", resume, overwrite, code=[dcstudies], conditions={"jobs": jobs})


@contextlib.contextmanager
def output_file(path, overwrite):
    """The one way a study's -o FILE is claimed: checked and locked before the study starts (a
    file there is replaced only with --overwrite), written by the block, atomically, at its end.
    None: no file (the block still runs)."""
    if not path:
        yield
        return
    with outputs.output_file(path, overwrite):
        yield


@contextlib.contextmanager
def _study_text(threads, output=None, overwrite=False):
    """The StudyText a text study reports into, each line echoed to stdout as it comes after the
    line saying how its times were taken; with `output`, the whole report written there at the end."""
    from deepcontact.protocol import protocol, protocol_line, use_threads
    from dcstudies.text import StudyText
    with output_file(output, overwrite):
        use_threads(threads)
        text = StudyText(sink=lambda part: click.echo(part, nl=False))
        text(protocol_line(protocol(threads)) + "\n")
        yield text
        if output:
            outputs.write_text(output, text.text())


@contextlib.contextmanager
def counting(quiet, total, unit, desc, work=None):
    """A text study's progress bar (terminal.progress_bar) for the block: its update, closed at the end."""
    bar = terminal.progress_bar(quiet, total, unit, desc, work=work)
    try:
        yield bar.update
    finally:
        bar.close()


@click.command("stability")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Also write the table to this file.")
@click.option("--fast", is_flag=True, help="The small variants the test suite runs.")
@click.option("--scenes", type=types.CommaList(click.STRING, "LABEL[,...]"),
              help="Only these scenes, by their labels in the table (e.g. 'stack 8,bullet').")
@options.jobs
@resumable
@options.overwrite
@options.verbosity
@options.command("study stability")
def stability(out, fast, scenes, jobs, resume, overwrite, verbose, quiet):
    """Run every hard scene with Box2D's solver and ours until it meets its criteria.

    Criteria (deepcontact/studies/stability.py): finite, penetration at rest
    within 3 linear slops, no energy gained, a stack's top within 1 cm. Where
    a configuration fails at the scene's 8 iterations, the count is doubled
    until it passes; the table gives that count. With -o, each run finished
    is kept until the table is written: --resume continues a stopped study. Box2D v3's rows count
    substeps (4 to 64), from its own rest. Exit 1 if any configuration of Box2D
    2.4.1 or ours never passes, or a v3 run becomes non-finite (v3 rows short
    of the criteria are listed on stderr).

    \b
    Examples:
      dc study stability --fast
      dc study stability --fast --scenes 'stack 8,bullet'
      dc study stability -o runs/stability.md --overwrite -j 2
      dc study stability -o runs/stability.md --resume
    """
    if not out:
        terminal.require_stdout("give -o FILE")
    from deepcontact.protocol import protocol, protocol_line
    from dcstudies import stability as S

    cases = options.pick_cases(S.FAST if fast else S.FULL, scenes)
    with keeping("stability", resume, overwrite, jobs), output_file(out, overwrite):
        measured = protocol(jobs=jobs)
        click.echo(S.HEADER)
        bar = terminal.progress_bar(quiet, len(S.tasks(cases)), "configuration", "study stability")
        try:
            rows = S.study(cases, log=click.echo, jobs=jobs, progress=bar.update)
        finally:
            bar.close()
        if out:
            outputs.write_text(out, S.markdown(rows, fast, protocol_line(measured)))
    # Other engines' rows are measured, not required: their contacts are what they are (a
    # non-finite state would still be a failure: of the model built for them, or of the binding)
    ours = ("box2d", "pgs")
    for engine in dict.fromkeys(f.solver for _, f in rows if f.solver not in ours):
        own = [f for _, f in rows if f.solver == engine]
        short = [f.case for f in own if not f.passed]
        if short:
            click.echo(f"{engine} meets the criteria on {len(own) - len(short)} of {len(own)} scenes up to "
                       f"{S.OWN_CAP} times its default effort; not on: {', '.join(short)} (see the table)", err=True)
    failed = sum(not f.passed if f.solver in ours else not f.finite for _, f in rows)
    if failed:
        from deepcontact.errors import StudyFailed
        raise StudyFailed(f"{failed} of {len(rows)} configurations never met their criteria (see the table)")


@click.command("engines")
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for engines.md, engines.csv and a Pareto plot per scene.")
@click.option("--fast", is_flag=True, help="The small variants the test suite runs (stability's, and a 30-circle pile), "
                                          "each engine at its few fast settings.")
@click.option("--scenes", type=types.CommaList(click.STRING, "LABEL[,...]"),
              help="Only these scenes, by their labels in the table (e.g. 'stack 20,pyramid 20').")
@options.families_option("Box2D v3,lagged")
@options.plugin_methods
@options.jobs
@resumable
@options.overwrite
@options.verbosity
@options.command("study engines")
def engines(out, fast, scenes, families, plugins, jobs, resume, overwrite, verbose, quiet):
    """What accuracy costs in time across engines: Box2D 2.4.1 at 1-256
    iterations, Box2D v3 at 1-16 substeps (and without warm starting), pymunk
    at 1-256 iterations, MuJoCo's Newton, CG and PGS at tolerances and caps
    (Newton also at the stiffer impedances 0.99 and 0.999), the project's
    solver to residuals 1e-2 ... 1e-8 (and its lagged body-space solve to
    1e-4 and 1e-8), on the thesis pile and every hard scene, each
    judged by the stability criteria and its drift from the reference
    trajectory (docs/results/engines.md, "Engines").

    Writes engines.md (the cheapest passing setting of each engine per scene,
    never one whose cap stopped steps above its tolerance: marked "cap hit on
    N steps" in the table per scene), engines.csv and pareto-SCENE.png. Times are one
    thread's; -j runs scenes side by side (each time is then taken beside
    another process: use -j 1 for the published table). Each setting measured
    on a scene is kept beside the output until it is written: after a stop,
    the same command with --resume measures only the rest.

    \b
    Examples:
      dc study engines --fast -o reports/engines-fast
      dc study engines -o reports/engines --scenes 'stack 20,mass ratio 400:1'
      dc study engines -o reports/lagged --families lagged
      dc study engines -o reports/peers --families 'pymunk,MuJoCo Newton'
      dc study engines --fast -o reports/mine --families project --accelerate mypkg.solvers:Mine
      dc study engines -o reports/engines --resume
    """
    from deepcontact.errors import OptionError
    from deepcontact.protocol import protocol, protocol_line
    from dcstudies import engines as E

    cases = options.pick_cases(E.FAST if fast else E.FULL, scenes)
    chosen = E.settings(options.pick_families(E.FAMILIES, families), options.described_methods(plugins), fast)
    with (keeping("engines", resume, overwrite, jobs),
          outputs.output_folder(out, E.ENGINE_FILES, overwrite, command="study engines") as work):
        measured = protocol(jobs=jobs)
        bar = terminal.progress_bar(quiet, E.tasks_count(cases, chosen), "setting", "study engines",
                                    work=E.tasks_work(cases, chosen))
        try:
            rows = E.study(cases, jobs=jobs, progress=bar.update, chosen=chosen)
        finally:
            bar.close()
        if not rows:
            raise OptionError("no setting applies to the chosen scenes", "--scenes")
        E.write(rows, work, fast, protocol_line(measured))
    click.echo(E.verdict_table(rows))


@click.command("frontier")
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for frontier.md, frontier.csv and a plot per scene.")
@click.option("--fast", is_flag=True, help="The small variants the test suite runs (a 30-circle pile, a base-5 pyramid).")
@click.option("--scenes", type=types.CommaList(click.STRING, "LABEL[,...]"),
              help="Only these scenes, by their labels in the table (e.g. 'pile 1000,pyramid 40').")
@options.families_option("Box2D 2.4.1,NNCG")
@click.option("--tolerances", type=types.CommaList(types.Finite(min=0, min_open=True), "TOL[,...]"),
              help="The project's tolerances  [default: 1e-2,1e-4,1e-6,1e-8; 1e-2,1e-4 with --fast]")
@click.option("--samples", type=types.count(min=1), default=4, show_default=True,
              help="Recorded steps per scene the one-step error is measured on (2 with --fast).")
@options.plugin_methods
@options.jobs
@resumable
@options.overwrite
@options.verbosity
@options.command("study frontier")
def frontier(out, fast, scenes, families, tolerances, samples, plugins, jobs, resume, overwrite, verbose, quiet):
    """What accuracy costs at scale: Box2D 2.4.1 at 1-256 iterations, Box2D v3
    at 1-16 substeps, pymunk at 1-256 iterations, MuJoCo's Newton, CG and PGS
    at tolerances and caps (Newton also at the stiffer impedances 0.99 and
    0.999), and the project's PGS, PSOR, NNCG and lagged body-space
    solve to residuals 1e-2 ... 1e-8 and at fixed budgets, on piles of 1,000
    and 10,000 circles, confined circles and pyramids of 820 and 5,050 boxes,
    each judged by its one-step residual from the same recorded states, its
    velocity error against the reference step, and the stability criteria
    (docs/results/frontier.md, "The frontier at scale").

    Writes frontier.md (for each engine setting, the cheapest project setting
    at least as accurate, never one whose cap stopped steps above its
    tolerance: marked "cap hit on N steps" in the table per scene), frontier.csv and
    frontier-SCENE.png. Times are one thread's; -j runs scenes side by side
    (each time then taken beside another process). The full study takes hours;
    --families and --tolerances run part of it (the summary then matches
    among the settings run), and each setting measured on a scene is kept
    beside the output until it is written: after a stop, the same command
    with --resume measures only the rest.

    \b
    Examples:
      dc study frontier --fast -o reports/frontier-fast
      dc study frontier -o reports/frontier --scenes 'pile 1000,pyramid 40'
      dc study frontier -o reports/big --scenes 'pyramid 5050' --tolerances 1e-2
      dc study frontier -o reports/frontier-engines --families 'Box2D 2.4.1,Box2D v3'
      dc study frontier -o reports/peers --scenes 'pile 1000' --families 'pymunk,MuJoCo Newton'
      dc study frontier -o reports/one --scenes 'pile 10000' --families 'MuJoCo Newton:tolerance 1e-08'
      dc study frontier --fast -o reports/mine --families PGS --accelerate mypkg.solvers:Mine
      dc study frontier -o reports/frontier --scenes 'pile 1000,pyramid 40' --resume
    """
    from deepcontact.errors import OptionError
    from deepcontact.protocol import protocol, protocol_line
    from dcstudies import frontier as F
    from dcstudies.engines import tasks_work

    cases = options.pick_cases(F.FAST if fast else F.SCALE, scenes)
    chosen = F.settings(fast, options.pick_families(F.FAMILIES, families), tolerances,
                        options.described_methods(plugins))
    if fast and not options.was_given("samples"):
        samples = F.FAST_SAMPLES
    with (keeping("frontier", resume, overwrite, jobs),
          outputs.output_folder(out, F.FRONTIER_FILES, overwrite, command="study frontier") as work):
        measured = protocol(jobs=jobs)
        bar = terminal.progress_bar(quiet, F.tasks_count(cases, chosen), "setting", "study frontier",
                                    work=tasks_work(cases, chosen))
        try:
            rows, lines = F.study(cases, chosen, samples, jobs=jobs, progress=bar.update)
        finally:
            bar.close()
        if not rows:
            raise OptionError("no setting applies to the chosen scenes", "--scenes")
        F.write(rows, lines, work, fast, protocol_line(measured))
    click.echo(F.summary_table(rows))


@click.command("figures")
@click.argument("run", metavar="RUN", type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Figures folder.")
@click.option("--every", type=types.count(min=1), default=10, show_default=True, help="Use every N-th step.")
@options.solve_to_tolerance
@options.jobs
@options.overwrite
@options.verbosity
@options.command("study figures")
def figures(run, out, every, tolerance, stop_on, max_iterations, jobs, overwrite, verbose, quiet):
    """The thesis's figures 5.4-5.7 on RUN: h, d and the kernel of the SPH start, then every start.

    Writes fig-5.4 ... fig-5.7 (PNG and SVG) and figures.md with each
    figure's table.

    \b
    Examples:
      dc study figures runs/heldout -o reports/figures
      dc study figures runs/heldout -o reports/figures --stop-on thesis --every 5
      dc study figures runs/heldout -o reports/figures -j 2
    """
    from deepcontact.solver.settings import SolveSettings
    from dcstudies.figures import FIGURE_FILES, figures as make, step_files

    with outputs.output_folder(out, FIGURE_FILES, overwrite, command="study figures") as work:
        bar = terminal.progress_bar(quiet, step_files(run), "step", "study figures")
        try:
            settings = SolveSettings(tolerance=tolerance, stop_on=stop_on, max_iterations=max_iterations)
            text = make(run, work, every=every, settings=settings, jobs=jobs, progress=bar.update)
        finally:
            bar.close()
        click.echo(text)


@click.command("scale")
@click.option("--samples", type=types.count(min=1), default=3, show_default=True,
              help="Settled steps solved per pile.")
@click.option("--cap", type=types.count(min=1), default=100_000, show_default=True, help="Iterations at most.")
@click.option("--quick", is_flag=True, help="Shorter settling, and no 10,000-circle pile.")
@click.option("--methods", type=types.CommaList(click.STRING, "LABEL[,...]"),
              help="Only these methods, by their labels (PGS, PSOR 1.7, NNCG, Newton, subspace, body space).")
@click.option("--sizes", type=types.CommaList(click.INT, "N[,...]"),
              help="Only the piles of these body counts (100, 1000, 10000).")
@text_report
@options.verbosity
@options.command("study scale")
def scale(samples, cap, quick, methods, sizes, threads, output, overwrite, verbose, quiet):
    """How the solver methods scale with the pile: time and iterations per
    step to a residual of 1e-4 at 100, 1,000 and 10,000 circles, from zero
    and from Box2D's warm start, and the fitted exponent of time against
    bodies (docs/results/bodyspace.md, "As the pile grows").

    \b
    Examples:
      dc study scale --samples 2 --sizes 100,1000
      dc study scale --samples 2 --sizes 10000 --methods 'PSOR 1.7,body space' --cap 2000
    """
    from dcstudies import scale as S
    unknown = [m for m in methods or () if m not in S.METHODS]
    if unknown:
        raise click.BadParameter(f"no method {unknown[0]!r}; the methods are: {', '.join(S.METHODS)}",
                                 param_hint="--methods")
    chosen = tuple(methods or S.METHODS)
    rows, work = S.rows_work(quick, chosen, sizes)
    with (_study_text(threads, output, overwrite) as text,
          counting(quiet, rows, "row", "study scale", work) as tick):
        S.run(samples=samples, cap=cap, quick=quick, methods=chosen, sizes=sizes, out=text, progress=tick)


@click.command("exact")
@click.option("--scene", type=click.Choice(["pile", "pyramid", "both", "hard"]), default="both", show_default=True,
              help="hard: the stability study's full-size hard scenes.")
@click.option("--every", type=types.count(min=1), default=5, show_default=True, help="Use every N-th step.")
@click.option("--siconos", is_flag=True, help="Siconos's Lemke on the same steps too (Debian's python3-siconos).")
@text_report
@options.verbosity
@options.command("study exact")
def exact(scene, every, siconos, threads, output, overwrite, verbose, quiet):
    """The reference solutions: how long reaching a residual of 1e-12 takes
    (sweeps, Newton, Lemke's pivots where Newton stalls), on held-out pile and
    pyramid steps or on the hard scenes (docs/results/exact.md, "An exact step").

    \b
    Examples:
      dc study exact --siconos
      dc study exact --scene hard --every 1
    """
    from dcstudies.exact import run, scenes
    options.refuse_inapplicable([("siconos", scene != "hard", "does not apply to --scene hard")])
    with (_study_text(threads, output, overwrite) as text,
          counting(quiet, scenes(scene), "scene", "study exact") as tick):
        run(scene, every, siconos, out=text, progress=tick)


@click.command("peer")
@click.option("--scene", type=click.Choice(["pile", "pyramid", "both", "pyramid40"]), default="both",
              show_default=True)
@click.option("--every", type=types.count(min=1), default=5, show_default=True, help="[pile] Use every N-th step.")
@click.option("--tolerances", type=types.CommaList(types.Finite(min=0, min_open=True), "TOL[,...]"),
              default="1e-4,1e-8", show_default=True)
@click.option("--cap", type=types.count(min=1), default=100_000, show_default=True,
              help="Our sweeps at most (Siconos: 100,000 iterations).")
@text_report
@options.verbosity
@options.command("study peer")
def peer(scene, every, tolerances, cap, threads, output, overwrite, verbose, quiet):
    """Our solver against Siconos's NSGS and Lemke on the same exported
    problems, from zero to each tolerance (docs/results/exact.md, "An exact step: Newton against PGS and Siconos").
    Needs Debian's python3-siconos (make setup).

    \b
    Examples:
      dc study peer
      dc study peer --scene pyramid40 --tolerances 1e-4
    """
    from dcstudies.peer import rows_count, run
    with (_study_text(threads, output, overwrite) as text,
          counting(quiet, rows_count(scene, tolerances), "row", "study peer") as tick):
        run(scene, every, tuple(tolerances), cap, out=text, progress=tick)


# The studies, as `dc study` lists them (pyproject.toml's entry points name these classes).
def _study(command, order, writes, summary):
    """The Study whose `dc study` command is `command`."""
    return type(command.name.capitalize(), (Study,), dict(
        name=command.name, order=order, writes=writes, summary=summary, command=staticmethod(lambda: command),
        __doc__=f"dc study {command.name}: {summary}."))


Stability = _study(stability, 0, "file", "the hard scenes under every engine and the project's solver: the effort "
                                          "each needs")
Engines = _study(engines, 1, "folder", "accuracy against time: Box2D 2.4.1, Box2D v3, pymunk, MuJoCo and the "
                                       "project's solver")
Frontier = _study(frontier, 2, "folder", "the same at scale: piles, confined circles and pyramids of thousands")
Figures = _study(figures, 3, "folder", "the thesis's convergence figures 5.4-5.7, regenerated with the SPH start")
Exact = _study(exact, 4, "text", "the reference solutions: time to 1e-12, pivots, the hard scenes")
Peer = _study(peer, 5, "text", "our solver against Siconos (NSGS, Lemke) on the same problems")
Scale = _study(scale, 6, "text", "every method's time to 1e-4 as the pile grows (100 to 10,000 circles)")
