"""dc simulate: scenes → per-step XML files."""
import re

import click

from deepcontact.errors import InputError

from . import options


def parse_seeds(seed, seeds):
    if seeds is None:
        return [seed]
    m = re.fullmatch(r"\s*(\d+)\s*\.\.\s*(\d+)\s*", seeds)
    if not m or int(m.group(1)) > int(m.group(2)):
        raise InputError(f"--seeds must look like A..B with A <= B (inclusive), got {seeds!r}")
    return list(range(int(m.group(1)), int(m.group(2)) + 1))


def parse_shard(shard, seeds):
    if shard is None:
        return seeds
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", shard)
    if not m or not int(m.group(1)) < int(m.group(2)):
        raise InputError(f"--shard must look like I/N with 0 <= I < N, got {shard!r}")
    i, n = int(m.group(1)), int(m.group(2))
    return seeds[i::n]


def loop_options(solver, start, mode, tolerance, max_iterations, stop_on, relaxation, first_scene, accelerate=None):
    """LoopOptions for --solver pgs (None for box2d); pgs options without it are an error."""
    given = {"--start": start, "--mode": mode, "--tolerance": tolerance, "--max-iterations": max_iterations,
             "--stop-on": stop_on, "--relaxation": relaxation, "--accelerate": accelerate}
    if solver == "box2d":
        used = [k for k, v in given.items() if v is not None]
        if used:
            raise InputError(f"{', '.join(used)} only apply with --solver pgs")
        return None
    from deepcontact.simulate.pgs_loop import LoopOptions
    mode = mode or "float64"
    if mode == "exact" and relaxation not in (None, 1.0):
        raise InputError("--mode exact is Box2D's PGS: it takes no --relaxation")
    if mode == "exact" and accelerate not in (None, "none"):
        raise InputError("--mode exact is Box2D's PGS: it takes no --accelerate")
    if relaxation == "auto" and not tolerance:
        raise InputError("--relaxation auto counts sweeps to a tolerance: give --tolerance")
    cap = max_iterations if max_iterations is not None else (
        first_scene.solver.velocity_iterations if first_scene is not None else 8)
    return LoopOptions(start=start or "builtin", mode=mode, max_iterations=cap, tolerance=tolerance or 0.0,
                       stop_on=stop_on or "residual", relaxation=relaxation or 1.0, accelerate=accelerate or "none")


def parse_params(pairs):
    params = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise InputError(f"--param takes key=value, got {pair!r}")
        params[key.strip()] = value.strip()
    return params


@click.command()
@click.argument("scene")
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False), help="Output folder.")
@click.option("--steps", type=int, help="Override the scene's number of steps.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Random seed.")
@click.option("--seeds", metavar="A..B", help="Simulate every seed from A to B (inclusive).")
@click.option("--shard", metavar="I/N", help="Only every N-th seed, starting at the I-th (0-based).")
@click.option("--param", "params", multiple=True, metavar="KEY=VALUE",
              help="A generator parameter (repeatable); see --list.")
@click.option("--iterations", type=int, help="Override Box2D's velocity iterations per step.")
@click.option("--skip-contactless", is_flag=True, help="Write no file for steps without contacts.")
@click.option("--write-scene", type=click.Path(dir_okay=False),
              help="Write the scene (for --seed) to this file and stop.")
@click.option("--list", "list_generators", is_flag=True, help="List generators and parameters, and stop.")
@click.option("--solver", type=click.Choice(["box2d", "pgs"]), default="box2d", show_default=True,
              help="Box2D's own velocity solver, or the project's PGS in the loop.")
@click.option("--start", type=click.Choice(["zero", "builtin", "garbage"]),
              help="[pgs] First iterate (default builtin); garbage: 1e30, NaN, -1 (a stability test).")
@click.option("--mode", type=click.Choice(["exact", "float32", "float64"]),
              help="[pgs] exact: Box2D's float32 arithmetic; float64: double precision (default).")
@click.option("--tolerance", type=options.Finite(min=0), help="[pgs] Stop when the measure falls below this.")
@click.option("--max-iterations", type=click.IntRange(min=0), help="[pgs] Sweep cap (default: the scene's).")
@click.option("--stop-on", type=click.Choice(["thesis", "velocity", "residual"]),
              help="[pgs] The measure the tolerance applies to (default residual).")
@click.option("--relaxation", type=options.Relaxation(),
              help="[pgs] Over-relaxation w in (0, 2) (PSOR; float64 mode), or auto: the w with the fewest sweeps "
                   "on the first 8 steps with contacts.")
@click.option("--accelerate", type=click.Choice(["none", "nncg"]),
              help="[pgs] nncg: conjugate directions on top of the sweeps (nonsmooth nonlinear conjugate "
                   "gradient; float32/float64 modes). Default none.")
@options.jobs
@options.max_memory
@options.overwrite
@options.verbosity
@options.command("simulate")
def simulate(scene, out_dir, steps, seed, seeds, shard, params, iterations, skip_contactless, write_scene,
             list_generators, solver, start, mode, tolerance, max_iterations, stop_on, relaxation, accelerate, jobs,
             max_memory, overwrite, verbose, quiet):
    """Simulate SCENE in Box2D and record every step as XML.

    SCENE is a scene file (schemas/scene.xsd) or a built-in generator: pile (the
    thesis world), stack, pyramid, mass-ratio, card-house, arch, confined,
    warm-start-energy, bullet. Each simulation gets a folder seed-NNNNNN/ holding
    scene.xml and step-NNNNNN.xml files; OUTDIR/manifest.json is written last.

    \b
    Examples:
      dc simulate pile -o runs/pile
      dc simulate pile --param count=70 --seeds 0..149 --jobs 2 -o runs/thesis
      dc simulate pile --seeds 0..149 --shard 1/4 -o runs/shard-1
      dc simulate stack --param count=24 --iterations 30 -o runs/stack
      dc simulate pile --seed 3 --write-scene pile-3.xml
      dc simulate my-scene.xml --steps 100 -o runs/mine
      dc simulate pile --solver pgs --start zero --tolerance 1e-4 --max-iterations 1000 -o runs/pgs
      dc simulate pile --solver pgs --tolerance 1e-4 --max-iterations 1000 --accelerate nncg --relaxation 1.3 -o runs/cg
    """
    from deepcontact import atomic
    from deepcontact.scene.generators import GENERATORS, parameters
    from deepcontact.scene.xml import to_xml
    from deepcontact.simulate.run import run
    from deepcontact.simulate.source import SceneSource

    if list_generators:
        for name in GENERATORS:
            defaults = " ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}"
                                for k, v in parameters(name).items())
            click.echo(f"{name}: {defaults}")
        return
    source = SceneSource(scene, parse_params(params), steps, iterations)
    source.check_memory(1, max_memory)
    if write_scene:
        import os
        if os.path.exists(write_scene) and not overwrite:
            raise InputError("file exists; use --overwrite to replace it", write_scene)
        atomic.write_bytes(write_scene, to_xml(source(seed)))
        return
    if not out_dir:
        raise InputError("missing -o/--output OUTDIR")
    seed_list = parse_shard(shard, parse_seeds(seed, seeds))
    source.check_memory(min(jobs, max(len(seed_list), 1)), max_memory)
    loop = loop_options(solver, start, mode, tolerance, max_iterations, stop_on, relaxation,
                        source(seed_list[0]) if seed_list else None, accelerate)
    bar = None if quiet else (lambda total: options.progress_bar(quiet, total, "step", f"simulate {scene}"))
    run(source, seed_list, out_dir, overwrite=overwrite, skip_contactless=skip_contactless, jobs=jobs,
        progress=bar, source=scene, loop=loop)
    if not quiet:
        click.echo(f"{out_dir}", err=False)
