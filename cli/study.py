"""dc study: the longer measurements (stability of the hard scenes, the thesis's figures, one map
or two, the grid's own loss, the learned correction and coarse space): every results table of
docs/results.md that is not a `dc evaluate` report comes from one of these."""
import contextlib

import click

from deepcontact.model.arch import NETWORKS
from deepcontact.studies import STUDIES

from . import options


class StudyGroup(click.Group):
    """`dc study`, built from the one table of studies (deepcontact.studies.STUDIES): its commands
    in the table's order, its help's list from the table's lines."""

    def list_commands(self, ctx):
        return [s.name for s in STUDIES if s.name in self.commands]

    def format_help_text(self, ctx, formatter):
        super().format_help_text(ctx, formatter)
        with formatter.section("Studies"):
            formatter.write_dl([(s.name, s.summary) for s in STUDIES])

    def format_commands(self, ctx, formatter):
        pass   # (the list above says what each does)


@click.group(cls=StudyGroup)
def study():
    """Longer measurements built on the pipeline.

    Every results table of docs/results.md that is not a `dc evaluate` report
    comes from one of these. With -o, a study writes a folder (tables, CSV and plots), a file (its
    table) or a text report (also echoed to stdout as it comes); a study whose
    verdict is a failure says so in one line and exits 1.

    \b
    Examples:
      dc study stability --fast
      dc study stability -o runs/stability.md
      dc study figures runs/heldout -o reports/figures --every 10
      dc study maps data/thesis -o reports/maps --epochs 10
      dc study oracle runs/pile --sweep -o reports/sph
    """


@study.command()
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Also write the table to this file.")
@click.option("--fast", is_flag=True, help="The small variants the test suite runs.")
@options.jobs
@options.overwrite
@options.verbosity
@options.command("study stability")
def stability(out, fast, jobs, overwrite, verbose, quiet):
    """Run every hard scene with Box2D's solver and ours until it meets its criteria.

    Criteria (deepcontact/studies/stability.py): finite, penetration at rest
    within 3 linear slops, no energy gained, a stack's top within 1 cm. Where
    a configuration fails at the scene's 8 iterations, the count is doubled
    until it passes; the table gives that count. Box2D v3's rows count
    substeps (4 to 64), from its own rest. Exit 1 if any configuration of Box2D
    2.4.1 or ours never passes, or a v3 run becomes non-finite (v3 rows short
    of the criteria are listed on stderr).

    \b
    Examples:
      dc study stability --fast
      dc study stability -o runs/stability.md --overwrite -j 2
    """
    if not out:
        options.require_stdout("give -o FILE")
    from deepcontact import atomic
    from deepcontact.protocol import protocol, protocol_line
    from deepcontact.studies import stability as S

    with output_file(out, overwrite):
        measured = protocol(jobs=jobs)
        click.echo(S.HEADER)
        rows = S.study(S.FAST if fast else S.FULL, log=click.echo, jobs=jobs)
        if out:
            atomic.write_text(out, S.markdown(rows, fast, protocol_line(measured)))
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


@study.command()
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for engines.md, engines.csv and a Pareto plot per scene.")
@click.option("--fast", is_flag=True, help="The small variants the test suite runs (stability's, and a 30-circle pile).")
@click.option("--scenes", type=options.CommaList(click.STRING, "LABEL[,...]"),
              help="Only these scenes, by their labels in the table (e.g. 'stack 20,pyramid 20').")
@options.families_option("Box2D v3,lagged")
@options.plugin_methods
@options.jobs
@options.overwrite
@options.verbosity
@options.command("study engines")
def engines(out, fast, scenes, families, plugins, jobs, overwrite, verbose, quiet):
    """What accuracy costs in time across engines: Box2D 2.4.1 at 1-256
    iterations, Box2D v3 at 1-16 substeps (and without warm starting), the
    project's solver to residuals 1e-2 ... 1e-8 (and its lagged body-space
    solve to 1e-4 and 1e-8), on the thesis pile and every hard scene, each
    judged by the stability criteria and its drift from the reference
    trajectory (docs/results.md, "Engines").

    Writes engines.md (the cheapest passing setting of each engine per scene,
    and a table per scene), engines.csv and pareto-SCENE.png. Times are one
    thread's; -j runs scenes side by side (each time is then taken beside
    another process: use -j 1 for the published table).

    \b
    Examples:
      dc study engines --fast -o reports/engines-fast
      dc study engines -o reports/engines --scenes 'stack 20,mass ratio 400:1'
      dc study engines -o reports/lagged --families lagged
      dc study engines --fast -o reports/mine --families project --accelerate mypkg.solvers:Mine
    """
    from deepcontact import atomic
    from deepcontact.errors import OptionError
    from deepcontact.protocol import protocol, protocol_line
    from deepcontact.studies import engines as E

    cases = options.pick_cases(E.FAST if fast else E.FULL, scenes)
    chosen = E.settings(options.pick_families(E.FAMILIES, families), options.described_methods(plugins))
    with atomic.output_folder(out, E.ENGINE_FILES, overwrite, command="study engines") as work:
        measured = protocol(jobs=jobs)
        bar = options.progress_bar(quiet, E.tasks_count(cases, chosen), "setting", "study engines")
        try:
            rows = E.study(cases, jobs=jobs, progress=bar.update, chosen=chosen)
        finally:
            bar.close()
        if not rows:
            raise OptionError("no setting applies to the chosen scenes", "--scenes")
        E.write(rows, work, fast, protocol_line(measured))
    click.echo(E.verdict_table(rows))


@study.command()
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for frontier.md, frontier.csv and a plot per scene.")
@click.option("--fast", is_flag=True, help="The small variants the test suite runs (a 30-circle pile, a base-5 pyramid).")
@click.option("--scenes", type=options.CommaList(click.STRING, "LABEL[,...]"),
              help="Only these scenes, by their labels in the table (e.g. 'pile 1000,pyramid 40').")
@options.families_option("Box2D 2.4.1,NNCG")
@click.option("--tolerances", type=options.CommaList(options.Finite(min=0, min_open=True), "TOL[,...]"),
              help="The project's tolerances  [default: 1e-2,1e-4,1e-6,1e-8; 1e-2,1e-4 with --fast]")
@click.option("--samples", type=options.count(min=1), default=4, show_default=True,
              help="Recorded steps per scene the one-step error is measured on (2 with --fast).")
@options.plugin_methods
@options.jobs
@options.overwrite
@options.verbosity
@options.command("study frontier")
def frontier(out, fast, scenes, families, tolerances, samples, plugins, jobs, overwrite, verbose, quiet):
    """What accuracy costs at scale: Box2D 2.4.1 at 1-256 iterations, Box2D v3
    at 1-16 substeps and the project's PGS, PSOR, NNCG and lagged body-space
    solve to residuals 1e-2 ... 1e-8 and at fixed budgets, on piles of 1,000
    and 10,000 circles, confined circles and pyramids of 820 and 5,050 boxes,
    each judged by its one-step residual from the same recorded states, its
    velocity error against the reference step, and the stability criteria
    (docs/results.md, "The frontier at scale").

    Writes frontier.md (for each engine setting, the cheapest project setting
    at least as accurate, and a table per scene), frontier.csv and
    frontier-SCENE.png. Times are one thread's; -j runs scenes side by side
    (each time then taken beside another process). The full study takes hours;
    --families and --tolerances run part of it (the summary then matches
    among the settings run).

    \b
    Examples:
      dc study frontier --fast -o reports/frontier-fast
      dc study frontier -o reports/frontier --scenes 'pile 1000,pyramid 40'
      dc study frontier -o reports/big --scenes 'pyramid 5050' --tolerances 1e-2
      dc study frontier -o reports/frontier-engines --families 'Box2D 2.4.1,Box2D v3'
      dc study frontier --fast -o reports/mine --families PGS --accelerate mypkg.solvers:Mine
    """
    from deepcontact import atomic
    from deepcontact.errors import OptionError
    from deepcontact.protocol import protocol, protocol_line
    from deepcontact.studies import frontier as F

    cases = options.pick_cases(F.FAST if fast else F.SCALE, scenes)
    chosen = F.settings(fast, options.pick_families(F.FAMILIES, families), tolerances,
                        options.described_methods(plugins))
    if fast and not options.was_given("samples"):
        samples = F.FAST_SAMPLES
    with atomic.output_folder(out, F.FRONTIER_FILES, overwrite, command="study frontier") as work:
        measured = protocol(jobs=jobs)
        bar = options.progress_bar(quiet, F.tasks_count(cases, chosen), "setting", "study frontier")
        try:
            rows, lines = F.study(cases, chosen, samples, jobs=jobs, progress=bar.update)
        finally:
            bar.close()
        if not rows:
            raise OptionError("no setting applies to the chosen scenes", "--scenes")
        F.write(rows, lines, work, fast, protocol_line(measured))
    click.echo(F.summary_table(rows))


@study.command()
@click.argument("run", metavar="RUN", type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Figures folder.")
@click.option("--every", type=options.count(min=1), default=10, show_default=True, help="Use every N-th step.")
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
    from deepcontact import atomic
    from deepcontact.solver.settings import SolveSettings
    from deepcontact.studies.figures import FIGURE_FILES, figures as make, step_files

    with atomic.output_folder(out, FIGURE_FILES, overwrite, command="study figures") as work:
        bar = options.progress_bar(quiet, step_files(run), "step", "study figures")
        try:
            settings = SolveSettings(tolerance=tolerance, stop_on=stop_on, max_iterations=max_iterations)
            text = make(run, work, every=every, settings=settings, jobs=jobs, progress=bar.update)
        finally:
            bar.close()
        click.echo(text)


@study.command()
@click.argument("dataset", type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Comparison folder.")
@click.option("--epochs", type=options.count(min=1), default=10, show_default=True)
@click.option("--arch", "model", type=click.Choice(NETWORKS.builtin()), default="fcn", show_default=True,
              help="The network trained three times.")
@options.deprecated_alias("--model", "--arch", "model")
@click.option("--width", type=options.count(min=1, max=4096), default=16, show_default=True, help="[fcn] Channels.")
@click.option("--loss", type=options.choice("loss"), default="masked",
              show_default=True)
@click.option("--seed", type=options.count(), default=0, show_default=True)
@options.plots("Draw each run's loss.png/svg; --no-plots writes the checkpoints, metrics and comparison alone.")
@options.overwrite
@options.verbosity
@options.command("study maps")
def maps(dataset, out, epochs, model, width, loss, seed, plots, overwrite, verbose, quiet):
    """One map or two: the same network trained on both impulse maps, and one per map.

    Trains three runs (joint, normal-only, tangent-only) into OUTPUT and
    compares them at the validation simulations' contact points
    (compare.md, compare.json).

    \b
    Examples:
      dc study maps data/thesis -o reports/maps --epochs 10
      dc study maps data/thesis -o reports/maps --arch thesis --loss contacts
    """
    from deepcontact import atomic
    from deepcontact.studies.maps import MAP_FILES, compare, write_comparison

    with atomic.output_folder(out, MAP_FILES, overwrite, command="study maps") as work:
        rows = compare(dataset, work, model=model, fcn_width=width, epochs=epochs, loss=loss, optimizer="adam",
                       lr=1e-3, batch_size=64, seed=seed, plots=plots)
        click.echo(write_comparison(work, rows))


@study.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", type=click.Path(file_okay=False), help="[--sweep] Report folder.")
@click.option("--sweep", is_flag=True, help="The thesis's sweep of kernel x d x h (figures 5.4-5.6): a table and a plot.")
@click.option("--kernel", type=options.choice("kernel"), default="poly6",
              show_default=True, help="SPH kernel.")
@click.option("--cell", type=options.Finite(min=0, min_open=True), default=0.5, show_default=True, help="Cell size d.")
@click.option("--smoothing", type=options.Finite(min=0, min_open=True), default=0.5, show_default=True,
              help="Smoothing length h.")
@click.option("--renormalize/--no-renormalize", default=True, show_default=True)
@click.option("--window", type=options.Window(), help="Grid window (default: the scenes' box).")
@click.option("--impulses", type=options.choice("impulses"), default="reference", show_default=True,
              help="Exact answers to push through the grid.")
@click.option("--every", type=click.IntRange(min=1), default=10, show_default=True, help="Use every N-th step file.")
@options.overwrite
@options.verbosity
@options.command("study oracle")
def oracle(runs, out, sweep, kernel, cell, smoothing, renormalize, window, impulses, every, overwrite, verbose, quiet):
    """The grid's own loss on RUNS: each step's exact impulses splatted onto
    the grid and read back at the contacts, the error and the time; the
    ceiling of any start learned on the grid.

    \b
    Examples:
      dc study oracle runs/pile
      dc study oracle runs/pile --impulses recorded --kernel spiky --cell 0.25 --smoothing 0.25
      dc study oracle runs/pile --sweep -o reports/sph
    """
    options.refuse_inapplicable([
        ("out", sweep, "only applies with --sweep (without it the table is printed)"),
        *[(name, not sweep, "does not apply with --sweep (it sweeps kernel, d and h)")
          for name in ("kernel", "cell", "smoothing")]])
    options.check_grid_options(kernel, cell, smoothing)
    oracle_report(runs, out, kernel, cell, smoothing, renormalize, window, impulses, every, sweep, overwrite, quiet)


def oracle_report(runs, out, kernel, cell, smoothing, renormalize, window, impulses, every, sweep, overwrite, quiet):
    """dc study oracle's work (and dc rasterize --oracle/--study's, their old spellings)."""
    from deepcontact import atomic
    from deepcontact.studies import sph_oracle as O
    from deepcontact.studies.sph_oracle import steps_of

    if sweep and not out:
        raise click.UsageError("--sweep needs -o REPORT_DIR")
    bar = options.progress_bar(quiet, None, "step", f"{impulses} impulses")
    try:
        spec, steps, _ = steps_of(runs, cell, smoothing, kernel, renormalize, window, impulses, every,
                                  log=lambda _: bar.update(1))
    finally:
        bar.close()
    if not sweep:
        click.echo(O.TABLE_HEADER)
        click.echo(O.table_row(O.round_trip(steps, spec, "oracle")))
        return
    with atomic.output_folder(out, O.STUDY_FILES, overwrite, command="study oracle") as work:
        rows = O.study(steps, (spec.x0, spec.y0, spec.x1, spec.y1), renormalize)
        click.echo(O.write_study(work, steps, rows, impulses, renormalize))


def text_report(f):
    """What a study that reports in text takes: --threads, and -o FILE with --overwrite (its report
    also written to FILE, atomically, once the study ends; checked and locked before it starts)."""
    f = options.overwrite(f)
    f = click.option("-o", "--output", "output", type=click.Path(dir_okay=False),
                     help="Also write the report to this file (once the study ends).")(f)
    return options.threads(f)


@contextlib.contextmanager
def output_file(path, overwrite):
    """The one way a study's -o FILE is claimed: checked and locked before the study starts (a
    file there is replaced only with --overwrite), written by the block, atomically, at its end.
    None: no file (the block still runs)."""
    import os

    from deepcontact import atomic
    from deepcontact.errors import InputError
    if not path:
        yield
        return
    atomic.check_replaceable(path)
    with atomic.locked(path):
        if os.path.exists(path) and not overwrite:
            raise InputError("file exists; use --overwrite to replace it", path)
        yield


@contextlib.contextmanager
def _study_text(threads, output=None, overwrite=False):
    """The StudyText a text study reports into, each line echoed to stdout as it comes after the
    line saying how its times were taken; with `output`, the whole report written there at the end."""
    from deepcontact import atomic
    from deepcontact.protocol import protocol, protocol_line, use_threads
    from deepcontact.studies.text import StudyText
    with output_file(output, overwrite):
        use_threads(threads)
        text = StudyText(sink=lambda part: click.echo(part, nl=False))
        text(protocol_line(protocol(threads)) + "\n")
        yield text
        if output:
            atomic.write_text(output, text.text())


def learned_study(name, seeds):
    """What both learned-start studies take: the pile's training seeds and steps, threads, -v/-q."""
    def bundle(f):
        for option in reversed([
                click.option("--train", "train_seeds", type=options.SeedList(), default=seeds, show_default=True,
                             help="Training seeds of the pile (held out: seed 1000)."),
                click.option("--steps", type=options.count(min=1), default=600, show_default=True),
                text_report, options.verbosity, options.command(f"study {name}")]):
            f = option(f)
        return f
    return bundle


@study.command("learned-correction")
@click.option("--epochs", type=options.count(min=1), default=6, show_default=True)
@click.option("--sweeps", type=options.count(min=1), default=32, show_default=True,
              help="Differentiable sweeps before the loss (8 misleads: it prefers zero to builtin).")
@click.option("--batch", type=options.count(min=1), default=16, show_default=True)
@click.option("--rounds", type=options.count(min=1), default=4, show_default=True, help="Message-passing rounds.")
@click.option("--width", type=options.count(min=1, max=4096), default=32, show_default=True)
@click.option("--lr", type=options.Finite(min=0, min_open=True), default=3e-4, show_default=True)
@learned_study("learned-correction", "0,1,2,3")
def learned_correction(epochs, sweeps, batch, rounds, width, lr, train_seeds, steps, threads, output, overwrite,
                       verbose, quiet):
    """Does a learned correction on the contact graph beat Box2D's warm start?
    Trains it on piles driven by our PGS, then solves held-out steps from
    builtin and from builtin + correction (docs/results.md). Minutes.

    \b
    Examples:
      dc study learned-correction --train 0,1 --steps 300
      dc study learned-correction --epochs 6 --sweeps 32
    """
    from deepcontact.studies.learned_correction import run
    with _study_text(threads, output, overwrite) as text:
        run(epochs=epochs, sweeps=sweeps, batch=batch, rounds=rounds, width=width, lr=lr, train_seeds=train_seeds,
            steps=steps, out=text)


@study.command("learned-coarse")
@click.option("--cell", type=options.Finite(min=0, min_open=True), default=4.0, show_default=True,
              help="Aggregate size (m).")
@click.option("--sweeps", type=options.count(min=1), default=8, show_default=True,
              help="Sweeps before and after the correction.")
@click.option("--epochs", type=options.count(min=1), default=4, show_default=True)
@click.option("--lr", type=options.Finite(min=0, min_open=True), default=1e-4, show_default=True,
              help="(1e-3 made the surrogate loss rise.)")
@learned_study("learned-coarse", "0,1")
def learned_coarse(cell, sweeps, epochs, lr, train_seeds, steps, threads, output, overwrite, verbose, quiet):
    """Does a learned coarse space help PGS? Aggregation weights trained
    through the solve, between sweeps, against sweeps alone and the unlearned
    space (docs/results.md). Minutes.

    \b
    Examples:
      dc study learned-coarse --train 0,1 --steps 300
      dc study learned-coarse --cell 4 --sweeps 8 --epochs 4
    """
    from deepcontact.studies.learned_coarse import run
    with _study_text(threads, output, overwrite) as text:
        run(cell=cell, sweeps=sweeps, epochs=epochs, lr=lr, train_seeds=train_seeds, steps=steps, out=text)


@study.command()
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for amortize.md and amortize.csv.")
@click.option("--fast", is_flag=True, help="A 100-circle pile (the test suite's).")
@options.overwrite
@options.verbosity
@options.command("study amortize")
def amortize(out, fast, overwrite, verbose, quiet):
    """What amortizing the body-space operator across steps could buy, measured
    on settled piles of 1,000 and 10,000 circles: one factorization against one
    Box2D step, contact points that change state per step, PCG iterations with a
    factor 1, 4 and 16 steps old, and a low-rank update's rank and time
    (docs/results.md, "Amortizing the body-space operator"). One thread.

    \b
    Examples:
      dc study amortize --fast -o reports/amortize-fast
      dc study amortize -o reports/amortize
    """
    from deepcontact import atomic
    from deepcontact.protocol import protocol, protocol_line, use_threads
    from deepcontact.studies import amortize as A
    use_threads(1)
    piles = A.FAST if fast else A.FULL
    with atomic.output_folder(out, A.AMORTIZE_FILES, overwrite, command="study amortize") as work:
        measured = protocol(1)
        bar = options.progress_bar(quiet, sum(settle + samples for _, settle, samples in piles.values()), "step",
                                   "study amortize")
        try:
            result = A.run(piles, progress=bar.update)
        finally:
            bar.close()
        result.protocol = protocol_line(measured)
        result.write(work)
    options.show_output(f"{out}/amortize.md", quiet)


@study.command()
@click.option("--samples", type=options.count(min=1), default=3, show_default=True,
              help="Settled steps solved per pile.")
@click.option("--cap", type=options.count(min=1), default=100_000, show_default=True, help="Iterations at most.")
@click.option("--quick", is_flag=True, help="Shorter settling, and no 10,000-circle pile.")
@click.option("--methods", type=options.CommaList(click.STRING, "LABEL[,...]"),
              help="Only these methods, by their labels (PGS, PSOR 1.7, NNCG, Newton, subspace, body space).")
@click.option("--sizes", type=options.CommaList(click.INT, "N[,...]"),
              help="Only the piles of these body counts (100, 1000, 10000).")
@text_report
@options.verbosity
@options.command("study scale")
def scale(samples, cap, quick, methods, sizes, threads, output, overwrite, verbose, quiet):
    """How the solver methods scale with the pile: time and iterations per
    step to a residual of 1e-4 at 100, 1,000 and 10,000 circles, from zero
    and from Box2D's warm start, and the fitted exponent of time against
    bodies (docs/results.md, "As the pile grows").

    \b
    Examples:
      dc study scale --samples 2 --sizes 100,1000
      dc study scale --samples 2 --sizes 10000 --methods 'PSOR 1.7,body space' --cap 2000
    """
    from deepcontact.studies import scale as S
    unknown = [m for m in methods or () if m not in S.METHODS]
    if unknown:
        raise click.BadParameter(f"no method {unknown[0]!r}; the methods are: {', '.join(S.METHODS)}",
                                 param_hint="--methods")
    with _study_text(threads, output, overwrite) as text:
        S.run(samples=samples, cap=cap, quick=quick, methods=tuple(methods or S.METHODS), sizes=sizes, out=text)


@study.command("global-families")
@click.option("--part", type=click.Choice(["pile", "exact", "two-level", "all"]), default="all", show_default=True,
              help="pile: the 1000-circle pile to 1e-4; exact: the base-20 pyramid's settling steps to 1e-12; "
                   "two-level: where PGS stalls on the pile, and a coarse correction or a local exact solve after it.")
@click.option("--steps", type=options.CommaList(options.count(), "K[,...]"), default="300,400,500,600,700,800",
              show_default=True, help="[pile, two-level] The pile's steps.")
@click.option("--cap", type=options.count(min=1), default=3000, show_default=True,
              help="[pile, two-level] Iterations of PSOR and ADMM, sweeps of the two-level tries, at most.")
@text_report
@options.verbosity
@options.command("study global-families")
def global_families(part, steps, cap, threads, output, overwrite, verbose, quiet):
    """Two other global families as numpy prototypes, by the work they need:
    ADMM on the impulses (plain and with Anderson acceleration) and an
    augmented Lagrangian with the friction cone projected, against PSOR and
    the solver's own solve in body space (docs/results.md, "Two other global
    families, as prototypes"); and two second levels after PGS's sweeps, a
    coarse correction on aggregates of bodies and Lemke's method on the
    worst contacts' neighbourhood (docs/results.md, "Where PGS stalls").

    \b
    Examples:
      dc study global-families --part pile --steps 300,500 --cap 3000
      dc study global-families --part exact
      dc study global-families --part two-level --steps 500 -o two-level.md
    """
    from deepcontact.studies.global_families import run
    with _study_text(threads, output, overwrite) as text:
        run(part, tuple(steps), cap, out=text)


@study.command()
@click.option("--scene", type=click.Choice(["pile", "pyramid"]), default="pile", show_default=True)
@click.option("--repeats", type=options.count(min=1), default=3, show_default=True,
              help="Timings per step (the best is kept).")
@click.option("--loop", is_flag=True, help="Our PGS driving the scene instead of replaying its settled steps.")
@click.option("--seeds", type=options.SeedList(), help="[--loop] The scene's seeds, pooled (default 0).")
@text_report
@options.verbosity
@options.command("study relaxation")
def relaxation(scene, repeats, loop, seeds, threads, output, overwrite, verbose, quiet):
    """Time to the same accuracy (residual 1e-4): Box2D's warm start against
    over-relaxation, NNCG, Newton and subspace steps and the prev start, as
    median sweeps and solve time against builtin in the same run
    (docs/results.md, "Faster to the same accuracy").

    \b
    Examples:
      dc study relaxation --scene pile
      dc study relaxation --scene pyramid --repeats 2
      dc study relaxation --scene pile --loop --seeds 0,1,2,3 --repeats 2
    """
    from deepcontact.studies.relaxation import run
    options.refuse_inapplicable([("seeds", loop, "only applies with --loop")])
    with _study_text(threads, output, overwrite) as text:
        run(scene, repeats, (seeds or (0,)) if loop else None, out=text)


@study.command()
@click.option("--scene", type=click.Choice(["pile", "pyramid", "both", "hard"]), default="both", show_default=True,
              help="hard: the stability study's full-size hard scenes.")
@click.option("--every", type=options.count(min=1), default=5, show_default=True, help="Use every N-th step.")
@click.option("--siconos", is_flag=True, help="Siconos's Lemke on the same steps too (Debian's python3-siconos).")
@text_report
@options.verbosity
@options.command("study exact")
def exact(scene, every, siconos, threads, output, overwrite, verbose, quiet):
    """The reference solutions: how long reaching a residual of 1e-12 takes
    (sweeps, Newton, Lemke's pivots where Newton stalls), on held-out pile and
    pyramid steps or on the hard scenes (docs/results.md, "Exact answers").

    \b
    Examples:
      dc study exact --siconos
      dc study exact --scene hard --every 1
    """
    from deepcontact.studies.exact import run
    options.refuse_inapplicable([("siconos", scene != "hard", "does not apply to --scene hard")])
    with _study_text(threads, output, overwrite) as text:
        run(scene, every, siconos, out=text)


@study.command()
@click.option("--scene", type=click.Choice(["pile", "pyramid", "both", "pyramid40"]), default="both",
              show_default=True)
@click.option("--every", type=options.count(min=1), default=5, show_default=True, help="[pile] Use every N-th step.")
@click.option("--tolerances", type=options.CommaList(options.Finite(min=0, min_open=True), "TOL[,...]"),
              default="1e-4,1e-8", show_default=True)
@click.option("--cap", type=options.count(min=1), default=100_000, show_default=True,
              help="Our sweeps at most (Siconos: 100,000 iterations).")
@text_report
@options.verbosity
@options.command("study peer")
def peer(scene, every, tolerances, cap, threads, output, overwrite, verbose, quiet):
    """Our solver against Siconos's NSGS and Lemke on the same exported
    problems, from zero to each tolerance (docs/results.md, "Against Siconos").
    Needs Debian's python3-siconos (make setup).

    \b
    Examples:
      dc study peer
      dc study peer --scene pyramid40 --tolerances 1e-4
    """
    from deepcontact.studies.peer import run
    with _study_text(threads, output, overwrite) as text:
        run(scene, every, tuple(tolerances), cap, out=text)
