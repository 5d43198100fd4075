"""Options and behaviour shared by every `dc` subcommand (rasterio style): -v/-q counted into
one log level, logs and progress on stderr, clean one-line errors unless -v."""
import functools
import logging
import sys

import click

from deepcontact.errors import InputError


class Finite(click.FloatRange):
    """A float option that must be finite (click's own ranges let nan and inf through)."""
    name = "finite float"

    def convert(self, value, param, ctx):
        import math
        value = super().convert(value, param, ctx)
        if not math.isfinite(value):
            self.fail(f"{value} is not a finite number", param, ctx)
        return value


class Relaxation(click.ParamType):
    """Over-relaxation: a w in (0, 2), or auto (chosen per scene from its first steps)."""
    name = "w|auto"

    def convert(self, value, param, ctx):
        from deepcontact.solver.relaxation import parse_relaxation
        try:
            return parse_relaxation(value)
        except ValueError as e:
            self.fail(str(e), param, ctx)


def verbosity(f):
    f = click.option("-v", "--verbose", count=True, help="More output; -v also shows tracebacks.")(f)
    f = click.option("-q", "--quiet", count=True, help="Less output: no progress bar, warnings only.")(f)
    return f


overwrite = click.option("--overwrite", is_flag=True,
                         help="Replace existing output: the new output is built beside it and swapped in "
                         "only when complete, so a failed or interrupted run keeps the old one.")
jobs = click.option("-j", "--jobs", type=click.IntRange(min=1), default=1, show_default=True,
                    help="Worker processes.")


def log_level(verbose, quiet):
    return max(logging.DEBUG, min(logging.ERROR, logging.INFO - 10 * verbose + 10 * quiet))


def setup_logging(verbose, quiet):
    logging.basicConfig(level=log_level(verbose, quiet), stream=sys.stderr,
                        format="%(levelname)s: %(message)s")
    for noisy in ("matplotlib", "PIL"):   # their debug output is not ours
        logging.getLogger(noisy).setLevel(max(logging.WARNING, log_level(verbose, quiet)))


def command(name):
    """Wraps a subcommand body: logging set-up, InputError → one line and exit 1,
    Ctrl-C → exit 130; tracebacks only with -v."""
    def decorate(f):
        @functools.wraps(f)
        def wrapper(*args, verbose=0, quiet=0, **kwargs):
            setup_logging(verbose, quiet)
            try:
                return f(*args, verbose=verbose, quiet=quiet, **kwargs)
            except InputError as e:
                if verbose:
                    raise
                click.echo(f"dc {name}: error: {e}", err=True)
                sys.exit(1)
            except KeyboardInterrupt:
                click.echo(f"dc {name}: interrupted; only complete files were written, and output being "
                           f"replaced (--overwrite) is as it was", err=True)
                sys.exit(130)
            except OSError as e:
                if verbose:
                    raise
                where = f"{e.filename}: " if getattr(e, "filename", None) else ""
                click.echo(f"dc {name}: error: {where}{e.strerror or e}", err=True)
                sys.exit(1)
        return wrapper
    return decorate


def progress_bar(quiet, total, unit, desc):
    """A tqdm bar on stderr, or None when quiet (tqdm also stays silent when stderr is no terminal)."""
    if quiet:
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit=unit, desc=desc, file=sys.stderr, dynamic_ncols=True, leave=False,
                disable=None)


max_memory = click.option("--max-memory", type=Finite(min=0, min_open=True), metavar="GB",
                          help="Refuse work estimated to need more memory than this (default 8).")
