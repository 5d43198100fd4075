"""dc simulate: scenes → per-step XML files."""
import click

from deepcontact.simulate.engines import ENGINES
from deepcontact.simulate.pgs_loop import STARTS as LOOP_STARTS
from deepcontact.solver.methods import SOLVERS, methods_help
from deepcontact.solver.pgs import MEASURES, MODES, ORDERS
from deepcontact.solver.settings import CAP, SolveSettings

from . import options, terminal, types


def seed_list(seed, seeds, shard):
    """The seeds to simulate, as a range: --seed alone, or --seeds A..B, thinned by --shard I/N."""
    chosen = seeds if seeds is not None else range(seed, seed + 1)
    if shard is not None:
        i, n = shard
        chosen = chosen[i::n]
    return chosen


def box2d_engine(solver, start, mode, tolerance, max_iterations, stop_on, relaxation, first_scene, accelerate=None,
                 order=None):
    """The Box2D 2.4.1 engine --solver asks for: Box2D's own solver, or the project's with its
    SolveSettings and start (--solver pgs); pgs options without it are an error."""
    from deepcontact.simulate.engines import Box2D
    given = {"--start": start, "--mode": mode, "--tolerance": tolerance, "--max-iterations": max_iterations,
             "--stop-on": stop_on, "--relaxation": relaxation, "--accelerate": accelerate, "--order": order}
    if solver == "box2d":
        used = [k for k, v in given.items() if v is not None]
        if used:
            raise click.UsageError(f"{', '.join(used)} only appl{'ies' if len(used) == 1 else 'y'} with --solver pgs")
        return Box2D()
    if accelerate is not None:
        options.load_solvers([accelerate])
    # A tolerance asks to converge: the cap is then dc evaluate's (CAP), not the scene's 8 sweeps,
    # which would stop nearly every step short of it without a word.
    cap = max_iterations if max_iterations is not None else CAP if tolerance else (
        first_scene.solver.velocity_iterations if first_scene is not None else 8)
    settings = SolveSettings(mode=mode or "float64", max_iterations=cap, tolerance=tolerance or 0.0,
                             stop_on=stop_on or "residual", relaxation=relaxation or 1.0, accelerate=accelerate or "none",
                             order=order or "island")
    return Box2D(solver=settings, start=start or "builtin")   # (the library's rules: exit 2 naming the option)


@click.command()
@click.argument("scene", required=False)
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False), help="Output folder.")
@click.option("--steps", type=types.count(min=1), help="Override the scene's number of steps.")
@click.option("--seed", type=types.OneSeed("--seeds"), default=0, show_default=True,
              help="Random seed (several: --seeds A..B).")
@click.option("--seeds", type=types.SeedRange(), help="Simulate every seed from A to B (inclusive).")
@click.option("--shard", type=types.Shard(),
              help="Only every N-th seed, starting at the I-th, I counted from 0: --seeds 0..149 --shard 0/4 keeps "
                   "0, 4, 8, ... (a job array's task index; docs/scaling.md).")
@click.option("--param", "params", multiple=True, type=types.KeyValue(),
              help="A generator parameter (repeatable); see --list.")
@click.option("--iterations", type=types.count(), help="Override Box2D's velocity iterations per step.")
@click.option("--skip-contactless", is_flag=True, help="Write no file for steps without contacts.")
@click.option("--compress", is_flag=True,
              help="Write step-NNNNNN.xml.gz (gzip, about 1/6 of the size); every reader, dc validate and "
                   "xmllint read both forms.")
@click.option("--write-scene", type=click.Path(dir_okay=False),
              help="Write the scene (for --seed) to this file and stop.")
@click.option("--list", "list_generators", is_flag=True, help="List generators and parameters, and stop.")
@click.option("--engine", type=types.PluginName(ENGINES), default="box2d", show_default=True,
              help="box2d: Box2D 2.4.1 (Debian's); box2d3: Box2D v3 (3.1, the soft step); pymunk (Chipmunk2D); "
                   "mujoco (a planar model); or a plug-in's (docs/engines.md).")
@click.option("--set", "engine_settings", multiple=True, type=types.KeyValue(),
              help="An engine setting (repeatable; docs/engines.md lists each engine's): pymunk iterations=20; "
                   "mujoco solver=cg, tolerance=1e-6, iterations=50; box2d3 substeps=8.")
@click.option("--substeps", cls=types.SoftStepOption, type=types.count(min=1), help="[box2d3] Substeps per step.")
@click.option("--contact-hertz", cls=types.SoftStepOption, type=types.Finite(min=0, min_open=True),
              help="[box2d3] Soft contact stiffness in Hz.")
@click.option("--damping-ratio", cls=types.SoftStepOption, type=types.Finite(min=0),
              help="[box2d3] Soft contact damping ratio.")
@click.option("--push-speed", cls=types.SoftStepOption, type=types.Finite(min=0),
              help="[box2d3] The most speed (m/s) used to push overlapping bodies apart.")
@click.option("--solver", type=click.Choice(["box2d", "pgs"]), default="box2d", show_default=True,
              help="Box2D 2.4.1's own velocity solver, or the project's PGS in the loop.")
@click.option("--start", type=types.choice(LOOP_STARTS),
              help="[pgs] First iterate (default builtin); garbage: 1e30, NaN, -1 (a stability test).")
@click.option("--mode", type=types.choice(MODES),
              help="[pgs] exact: Box2D's float32 arithmetic (a step at 8 sweeps costs about 0.92x Box2D's "
                   "own on the settled 1000-circle pile); float64: double precision (default; about 1.04x "
                   "there: docs/results/step-price.md).")
@click.option("--tolerance", type=types.Finite(min=0),
              help="[pgs] Stop when the measure falls below this. A converged pile is a reference, "
                   "not a fast mode: the settled 1000-circle pile to 1e-4 costs about 40x Box2D's "
                   "step (PSOR 1.7) and still ends most steps above it at the cap "
                   "(docs/results/bodyspace.md, \"Converged piles\").")
@click.option("--max-iterations", type=types.count(),
              help=f"[pgs] Sweep cap (default: {CAP} with --tolerance, as dc evaluate's; else the scene's).")
@click.option("--stop-on", type=types.choice(MEASURES),
              help="[pgs] The measure the tolerance applies to (default residual).")
@click.option("--relaxation", type=types.Relaxation(),
              help="[pgs] Over-relaxation w in (0, 2) (PSOR; float64 mode), or auto: the w with the fewest sweeps "
                   "on the first 8 steps with contacts.")
@click.option("--accelerate", type=types.PluginName(SOLVERS),
              help=f"[pgs] The solver method (default none): {methods_help()}. Without --tolerance, the global "
                   f"methods solve to 1e-12.")
@click.option("--order", type=types.choice(ORDERS),
              help="[pgs] The order a sweep visits the contacts in: island (Box2D's, the default) or gravity "
                   "(from the highest to the lowest, so a sweep carries a pile's weight down it; at 2-4 sweeps "
                   "the settled 1000-circle pile's one-step residual is 0.60-0.95x island order's: "
                   "docs/results/frontier.md). Not with --mode exact (Box2D's own order).")
@options.jobs
@options.max_memory
@click.option("--max-disk", type=types.Finite(min=0, min_open=True), metavar="GB",
              help="Refuse a run estimated to write more than this (the free space is always a limit).")
@options.overwrite
@options.verbosity
@options.unfenced
@options.command("simulate")
def simulate(scene, out_dir, steps, seed, seeds, shard, params, iterations, skip_contactless, compress, write_scene,
             list_generators, engine, engine_settings, substeps, contact_hertz, damping_ratio, push_speed, solver, start, mode, tolerance, max_iterations, stop_on, relaxation, accelerate, order,
             jobs, max_memory, max_disk, overwrite, verbose, quiet):
    """Simulate SCENE in Box2D 2.4.1 (or another --engine) and record every step as XML.

    SCENE is a scene file (schemas/scene.xsd) or a built-in generator: pile (the
    thesis world), stack, pyramid, mass-ratio, card-house, arch, confined,
    warm-start-energy, bullet. Each simulation gets a folder seed-NNNNNN/ holding
    scene.xml and step-NNNNNN.xml files (step-NNNNNN.xml.gz with --compress);
    OUTDIR/manifest.json is written last.

    \b
    Examples:
      dc simulate pile -o runs/pile
      dc simulate pile --param count=70 --seeds 0..149 --jobs 2 -o runs/thesis
      dc simulate pile --seeds 0..149 --jobs 2 --compress -o runs/thesis-gz
      dc simulate pile --seeds 0..149 --shard 1/4 -o runs/shard-1
      dc simulate stack --param count=24 --iterations 30 -o runs/stack
      dc simulate pile --seed 3 --write-scene pile-3.xml
      dc simulate my-scene.xml --steps 100 -o runs/mine
      dc simulate pile --solver pgs --start zero --tolerance 1e-4 --max-iterations 1000 -o runs/pgs
      dc simulate pile --solver pgs --tolerance 1e-4 --max-iterations 1000 --accelerate nncg --relaxation 1.3 -o runs/cg
      dc simulate pile --solver pgs --mode float32 --order gravity -o runs/down
      dc simulate pile --engine box2d3 -o runs/pile-v3
      dc simulate stack --engine box2d3 --substeps 8 -o runs/stack-v3
      dc simulate pile --engine pymunk --set iterations=20 -o runs/pile-pymunk
      dc simulate pile --engine mujoco --set solver=cg --set tolerance=1e-6 -o runs/pile-mujoco
    """
    from deepcontact import output
    from deepcontact.scene.xml import to_xml
    from deepcontact.simulate.run import run
    from deepcontact.simulate.source import SceneSource

    _refuse_inapplicable(seeds is not None, write_scene, solver, engine)
    if list_generators:   # (no SCENE needed)
        _list_generators()
        return
    if scene is None:
        raise click.UsageError("missing SCENE: a generator (see --list) or a scene file")
    source = SceneSource(scene, types.key_values(params, "--param"), steps, iterations)
    source.check_memory(1, max_memory)
    if write_scene:
        with output.output_file(write_scene, overwrite):
            output.write_bytes(write_scene, to_xml(source(seed)))
        return
    if not out_dir:
        raise click.UsageError("missing -o/--output OUTDIR")
    chosen = seed_list(seed, seeds, shard)
    source.check_memory(min(jobs, max(len(chosen), 1)), max_memory)
    first = source(chosen[0]) if chosen and solver == "pgs" else None   # (its iterations: the loop's cap)
    box2d = box2d_engine(solver, start, mode, tolerance, max_iterations, stop_on, relaxation, first, accelerate, order)
    soft = {"substeps": substeps, "contact_hertz": contact_hertz, "damping_ratio": damping_ratio,
            "push_speed": push_speed}
    stepper = _engine(engine, types.key_values(engine_settings, "--set"), solver, box2d, soft)

    def bar(total):
        return terminal.progress_bar(quiet, total, "step", f"simulate {scene}")
    run(source, chosen, out_dir, overwrite=overwrite, skip_contactless=skip_contactless, jobs=jobs,
        progress=bar, source=scene, engine=stepper, max_disk=max_disk, compress=compress)
    terminal.show_output(f"{out_dir}", quiet)


def _refuse_inapplicable(given_seeds, write_scene, solver, engine):
    """The options that do not apply with the others given, refused (exit 2)."""
    options.refuse_inapplicable([
        ("seed", not given_seeds, "and --seeds: give one (--seed for one simulation, --seeds A..B for several)"),
        ("shard", given_seeds, "only applies with --seeds (it splits their range)"),
        ("out_dir", not write_scene, "does not apply with --write-scene (it writes the scene and stops)"),
        ("iterations", solver == "box2d" and engine == "box2d",
         "is Box2D 2.4.1's velocity iterations; with --solver pgs the cap is --max-iterations, and Box2D v3 "
         "(--engine box2d3) has substeps (--substeps)"),
        ("solver", engine == "box2d", "only applies with --engine box2d (pgs steps Box2D 2.4.1's worlds; another "
                                      "engine solves with its own solver)"),
        *((name, engine == "box2d3", "only applies with --engine box2d3")
          for name in ("substeps", "contact_hertz", "damping_ratio", "push_speed")),
    ])


def _list_generators():
    """--list: each generator with its parameters' defaults."""
    from deepcontact.scene.generators import GENERATORS, parameters
    for name in GENERATORS:
        defaults = " ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}"
                            for k, v in parameters(name).items())
        click.echo(f"{name}: {defaults}")


def _engine(engine, settings, solver, box2d, soft):
    """The engine --engine names, with its --set settings (and v3's own flags, `soft`)."""
    if engine == "box2d3":   # (its own flags beside --set, checked by SoftStep naming each)
        from deepcontact.simulate.engines import Box2D3, SoftStep
        return Box2D3(SoftStep(**{**Box2D3.parsed(settings), **{k: v for k, v in soft.items() if v is not None}}))
    if engine == "box2d":
        if settings and solver == "pgs":
            raise click.UsageError("--set applies to Box2D's own solver; the project's has --max-iterations")
        return box2d if not settings else type(box2d).from_settings(**settings)
    if engine in ENGINES.builtin():
        from deepcontact.simulate.engines import engine_named
        return engine_named(engine, settings)
    # a plug-in engine: its code only in a sandbox of its own (deepcontact/contest/engine.py)
    from deepcontact.contest.engine import guest_engine
    return guest_engine(engine, settings)
