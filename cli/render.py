"""dc render: pictures of steps, runs and grid samples, and a run viewer in one HTML file."""
from pathlib import Path

import click

from deepcontact.errors import InputError

from deepcontact.model.arch import BUILTIN as BUILTIN_NETWORKS

from . import fenced_training, options, terminal, types


FORMS = {"step": (".png", ".svg"), "run": (".gif", ".mp4", ".webm", ".html"), "dataset": (".png",)}


def kind_of(path):
    """What INPUT is: a step file, a run (or one simulation folder of it), or a grid dataset."""
    p = Path(path)
    if p.is_file():
        return "step"
    if not p.exists():
        raise InputError("no such file or folder", p)
    if (p / "metadata.json").is_file():
        return "dataset"
    return "run"


@click.command(cls=fenced_training.RawArgsCommand)
@click.argument("input_path", metavar="INPUT", type=click.Path())
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="The picture, movie or page; its extension chooses the form: .png/.svg (a step or a "
                   "dataset sample), .gif/.mp4/.webm/.html (a run).")
@click.option("--size", type=click.IntRange(min=64, max=4096), default=640, show_default=True,
              help="Width of the picture (or of each panel) in pixels.")
@click.option("--window", type=types.Window(), help="The part of the world to draw (default: around the bodies).")
@click.option("--no-contacts", is_flag=True, help="Draw no contact points or impulses.")
@click.option("--impulse-scale", type=types.Finite(min=0, min_open=True), metavar="M",
              help="Metres of arrow per N·s of impulse (default: the run's own, a median normal impulse drawn as "
                   "1/30 of the width; the same for a step, a movie and a viewer of one run). Give one to compare "
                   "pictures of different runs.")
@click.option("--color-by", type=click.Choice(["type", "speed"]), default="type", show_default=True,
              help="Fill bodies by type (static, kinematic, dynamic) or by speed.")
@click.option("--seed", type=types.count(), help="[run] The simulation to draw (default: the run's first).")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True, help="[run] Every k-th step.")
@click.option("--fps", type=click.IntRange(min=1, max=120), default=30, show_default=True, help="[run] Frame rate.")
@click.option("--compare", type=click.Path(file_okay=False),
              help="[run] A second run drawn beside the first, step for step, with the largest distance "
                   "between the same body in both.")
@click.option("--sample", type=types.count(), default=0, show_default=True, help="[dataset] The sample to draw.")
@options.checkpoint("[dataset] A checkpoint from dc train: its prediction and error beside each label.",
                    "[dataset] Load this network plug-in for a checkpoint that needs it.")
@options.threads
@options.jobs
@options.overwrite
@options.verbosity
@options.unfenced
@options.command("render")
def render(input_path, out, size, window, no_contacts, impulse_scale, color_by, seed, every, fps, compare, sample, model,
           arch, threads, jobs, overwrite, verbose, quiet):
    """Draw INPUT: a step file, a run, or a sample of a grid dataset.

    \b
    A step file -> PNG or SVG: static geometry, bodies, contact points with
      normal (red) and friction (blue) impulse arrows scaled and coloured
      by magnitude, and the scene, seed, step and time.
    A run (or one seed-NNNNNN folder of it) -> GIF, MP4 or WebM (every k-th
      step, a progress bar and a step counter; --compare draws a second run
      beside it), or HTML: a run viewer in one file (play, step slider,
      toggles for contacts and impulses, each step's numbers; no network).
    A grid dataset -> PNG: the sample's input channels and labels as panels,
      with --checkpoint the prediction and its error beside each label.

    MP4 and WebM need Debian's ffmpeg. Output is written atomically.

    \b
    Examples:
      dc render runs/demo/seed-000000/step-000599.xml -o pile.png
      dc render runs/demo/seed-000000/step-000300.xml --color-by speed -o pile.svg
      dc render runs/demo -o pile.gif --every 4 --fps 25
      dc render runs/demo -o pile.mp4 -j 2
      dc render runs/demo --compare runs/psor -o box2d-vs-psor.mp4 --every 2
      dc render runs/demo -o pile.html --every 2
      dc render data/thesis --sample 120 --checkpoint models/fcn/best.pt -o sample.png
    """
    from deepcontact import output

    kind = kind_of(input_path)
    suffix = Path(out).suffix.lower()
    _refuse_inapplicable(kind, suffix, model, no_contacts)
    from deepcontact.contest.fence import fenced
    if fenced(arch is not None and arch not in BUILTIN_NETWORKS):
        # a plug-in network's code runs to predict: the whole drawing runs fenced, as a study does
        from deepcontact.contest import job
        raise click.exceptions.Exit(job.run_with_output(
            ["render"], click.get_current_context().meta["raw_args"], "render", lambda: "file", {},
            f"dc render with the network {arch!r}", profile="drawing"))
    options.load_network(arch)
    _check_drawing(kind, suffix, compare, window)
    out = Path(out)
    with output.output_file(out, overwrite):
        if kind == "step":
            _step(input_path, out, size, window, not no_contacts, color_by, suffix[1:], impulse_scale)
        elif kind == "dataset":
            from deepcontact.render.panels import sample_panels
            output.write_bytes(out, sample_panels(input_path, sample, model, threads=threads))
        else:
            _run(input_path, out, size, window, not no_contacts, color_by, seed, every, fps, compare, quiet,
                 impulse_scale, jobs)
    terminal.show_output(str(out), quiet)


def _refuse_inapplicable(kind, suffix, model, no_contacts):
    """The options that do not apply to what is drawn, refused (exit 2)."""
    movie = suffix in (".gif", ".mp4", ".webm", ".html")
    options.refuse_inapplicable(
        [(name, kind == "run", "only applies to a run") for name in ("seed", "every", "compare")]
        + [("fps", kind == "run" and movie, "only applies to a run drawn as a movie or a viewer")]
        + [(name, kind == "dataset", "only applies to a grid dataset's sample")
           for name in ("sample", "model")]
        + [("arch", model is not None, "only applies with --checkpoint")]
        + [(name, kind != "dataset", "does not apply to a grid dataset's sample (it draws grid images)")
           for name in ("size", "window", "no_contacts", "color_by", "impulse_scale")]
        + [("impulse_scale", not no_contacts, "draws impulse arrows: it does not apply with --no-contacts")]
        + [("threads", model is not None, "only applies with --checkpoint (nothing else runs torch)")]
        + [("jobs", kind == "run" and movie and suffix != ".html", "draws a movie's frames side by side: it only "
                                                                    "applies to a run drawn as .gif, .mp4 or .webm")])


def _check_drawing(kind, suffix, compare, window):
    """The output's form for what is drawn, --compare's and the window's size (exit 2 for either)."""
    if suffix not in FORMS[kind]:
        every_form = sorted({s for forms in FORMS.values() for s in forms})
        if suffix in every_form:
            raise click.BadParameter(f"a {kind} is drawn as {' or '.join(FORMS[kind])}, not {suffix}",
                                     param_hint="'-o' / '--output'")
        raise click.BadParameter(f"unknown extension {suffix or '(none)'!r}: choose one of {', '.join(every_form)}",
                                 param_hint="'-o' / '--output'")
    if compare and suffix not in (".gif", ".mp4", ".webm"):
        raise click.UsageError("--compare draws two runs into a .gif, .mp4 or .webm")
    if window and min(window[2] - window[0], window[3] - window[1]) < MIN_WINDOW:
        # float32 positions resolve no finer, and the drawing's cost grows with the magnification
        raise click.BadParameter(f"a window narrower than {MIN_WINDOW:g} m shows nothing a step file resolves",
                                 param_hint="'--window'")


MIN_WINDOW = 1e-4   # metres


def _step(path, out, size, window, contacts, color_by, fmt, impulse_scale=None):
    from deepcontact import output
    from deepcontact.render.draw import Painter, Window
    from deepcontact.render.frames import run_impulse_scale, title, window_for
    from deepcontact.render.shapes import read_shapes
    from deepcontact.step.reader import read_step
    from deepcontact.step.run_folder import STEP_FILE

    header, bodies, contacts_ = read_step(path)
    shapes = read_shapes(path)
    win = Window(*window) if window else window_for(shapes, [(header, bodies, contacts_)])
    if impulse_scale is None and contacts:   # the simulation's scale, as its movie and viewer use
        siblings = sorted((f for f in Path(path).parent.iterdir() if STEP_FILE.fullmatch(f.name)),
                          key=lambda f: int(STEP_FILE.fullmatch(f.name).group(1)))
        impulse_scale = run_impulse_scale(siblings or [path])
    painter = Painter(shapes, win, size, contacts=contacts, color_by=color_by, impulse_scale=impulse_scale)
    painter.draw(bodies, contacts_, title(header, bodies, contacts_))
    output.write_bytes(out, painter.image_bytes(fmt))


def _run(path, out, size, window, contacts, color_by, seed, every, fps, compare, quiet, impulse_scale=None, jobs=1):
    import logging

    from deepcontact import output
    from deepcontact.render.draw import Window
    from deepcontact.render.frames import drawn, painter_for, simulation_files, write_gif, write_video

    clip = simulation_files(path, seed, every)
    if out.suffix.lower() == ".html":
        from deepcontact.render.viewer import viewer_html
        output.write_text(out, viewer_html(clip, size, fps, impulse_scale=impulse_scale,
                                           window=Window(*window) if window else None))
        return
    other = simulation_files(compare, seed, every) if compare else None
    if other is not None and (other.scene, other.seed) != (clip.scene, clip.seed):
        logging.getLogger("deepcontact.cli").warning(
            "the runs compared are different simulations (%s seed %s against %s seed %s): the distance between "
            "them measures that, not a solver", clip.scene, clip.seed, other.scene, other.seed)
    painter = painter_for(clip, size, contacts, color_by, Window(*window) if window else None,
                          panels=2 if other else 1, impulse_scale=impulse_scale)
    bar = terminal.progress_bar(quiet, len(clip.files), "frame", f"render {out.name}")
    gif = out.suffix.lower() == ".gif"
    stream = drawn(clip, painter, other, jobs=jobs, gif_fps=fps if gif else None, progress=bar.update)
    try:
        if gif:
            write_gif(out, stream)
        else:
            w, h = painter.size
            write_video(out, stream, fps, (w * (2 if other else 1), h))
    finally:
        bar.close()
