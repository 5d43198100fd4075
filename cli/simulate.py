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
@options.jobs
@options.overwrite
@options.verbosity
@options.command("simulate")
def simulate(scene, out_dir, steps, seed, seeds, shard, params, iterations, skip_contactless, write_scene,
             list_generators, jobs, overwrite, verbose, quiet):
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
    if write_scene:
        import os
        if os.path.exists(write_scene) and not overwrite:
            raise InputError("file exists; use --overwrite to replace it", write_scene)
        atomic.write_bytes(write_scene, to_xml(source(seed)))
        return
    if not out_dir:
        raise InputError("missing -o/--output OUTDIR")
    seed_list = parse_shard(shard, parse_seeds(seed, seeds))
    bar = None if quiet else (lambda total: options.progress_bar(quiet, total, "step", f"simulate {scene}"))
    run(source, seed_list, out_dir, overwrite=overwrite, skip_contactless=skip_contactless, jobs=jobs,
        progress=bar, source=scene)
    if not quiet:
        click.echo(f"{out_dir}", err=False)
