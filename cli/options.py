"""Options and behaviour shared by every `dc` subcommand (rasterio style): -v/-q counted into
one log level, logs and progress on stderr, clean one-line errors unless -v."""
import functools
import io
import logging
import signal
import sys

import click

from deepcontact import interrupts, output
from deepcontact.errors import Failure, InputError, OptionError, one_line, show_path
from deepcontact.interrupts import Terminated


class Finite(click.FloatRange):
    """A float option that must be finite (click's own ranges let nan and inf through)."""
    name = "finite float"

    def convert(self, value, param, ctx):
        import math
        value = super().convert(value, param, ctx)
        if not math.isfinite(value):
            self.fail(f"{value} is not a finite number", param, ctx)
        return value


INT32_MAX = 2 ** 31 - 1   # iteration and step counts: what Box2D and the native solver take


def count(min=0, max=INT32_MAX):
    """A whole-number option within what the native code takes."""
    return click.IntRange(min=min, max=max)


class Relaxation(click.ParamType):
    """Over-relaxation: a w in (0, 2), or auto (chosen per scene from its first steps)."""
    name = "w|auto"

    def convert(self, value, param, ctx):
        from deepcontact.solver.relaxation import parse_relaxation
        try:
            return parse_relaxation(value)
        except ValueError as e:
            self.fail(str(e), param, ctx)


class CommaList(click.ParamType):
    """Comma-separated values, each converted by `item` (a click type) and given once; at least one."""
    name = "list"

    def __init__(self, item=None, metavar=None):
        self.item = item
        self.name = metavar or (f"{item.name}[,...]" if item is not None else "a,b,...")

    def convert(self, value, param, ctx):
        if isinstance(value, list):
            return value
        parts = [t.strip() for t in str(value).split(",") if t.strip()]
        if not parts:
            self.fail(f"give at least one value, comma-separated; got {value!r}", param, ctx)
        if self.item is not None:
            parts = [self.item.convert(t, param, ctx) for t in parts]
        twice = [t for i, t in enumerate(parts) if t in parts[:i]]
        if twice:
            self.fail(f"{twice[0]} is listed twice", param, ctx)
        return parts


class PluginName(click.ParamType):
    """A name a registry (deepcontact.plugins.Registry) can resolve: a built-in, an installed
    plug-in or package.module:Name. Only the form is checked here; loading is the command's."""
    name = "name"

    def __init__(self, registry, extra=()):
        self.registry, self.extra = registry, tuple(extra)   # extra: words of the option's own (all)

    def convert(self, value, param, ctx):
        if value not in self.extra and not self.registry.is_name(value):
            choices = ", ".join(self.registry.names() + list(self.extra))
            self.fail(f"{value!r} is not a {self.registry.kind}: choose from {choices}, "
                      f"or name a plug-in as package.module:Name", param, ctx)
        return value


class Parsed(click.ParamType):
    """A text option parsed by `parse`, which raises ValueError with the reason; a value that
    is already parsed (a default given as such) passes through."""

    def parse(self, text):
        raise NotImplementedError

    def convert(self, value, param, ctx):
        if not isinstance(value, str):
            return value
        try:
            return self.parse(value)
        except ValueError as e:
            self.fail(f"{e}; got {value!r}", param, ctx)


class Window(Parsed):
    """x0,y0,x1,y1: four finite numbers with x0 < x1 and y0 < y1."""
    name = "x0,y0,x1,y1"

    def parse(self, text):
        import math
        try:
            values = tuple(float(t) for t in text.split(","))
        except ValueError:
            values = ()
        if len(values) != 4 or not all(math.isfinite(v) for v in values):
            raise ValueError("takes four finite numbers x0,y0,x1,y1")
        if not (values[0] < values[2] and values[1] < values[3]):
            raise ValueError("needs x0 < x1 and y0 < y1")
        return values


def _two_whole_numbers(pattern, text, problem):
    import re
    m = re.fullmatch(pattern, text)
    if not m:
        raise ValueError(problem)
    return int(m.group(1)), int(m.group(2))


class SeedList(Parsed):
    """Seeds separated by commas (0,1,2), as a tuple of whole numbers."""
    name = "A,B,..."

    def parse(self, text):
        parts = [t.strip() for t in str(text).split(",")]
        if not parts or not all(t.isdigit() and int(t) <= INT32_MAX for t in parts):
            raise ValueError(f"must be seeds separated by commas (whole numbers 0 to {INT32_MAX}), got {text!r}")
        return tuple(int(t) for t in parts)


class SeedRange(Parsed):
    """A..B, inclusive, as a range (never a list: a billion seeds cost nothing until used)."""
    name = "A..B"

    def parse(self, text):
        problem = f"must look like A..B with 0 <= A <= B <= {INT32_MAX} (inclusive)"
        a, b = _two_whole_numbers(r"\s*(\d+)\s*\.\.\s*(\d+)\s*", text, problem)
        if a > b or b > INT32_MAX:
            raise ValueError(problem)
        return range(a, b + 1)


class Shard(Parsed):
    """I/N: every N-th item, starting at the I-th, counted from 0 (I = 0 .. N-1: a job array's task
    index as it comes)."""
    name = "I/N"

    def parse(self, text):
        problem = "must look like I/N with 0 <= I < N (I counts from 0: --shard 0/4 ... --shard 3/4)"
        i, n = _two_whole_numbers(r"\s*(\d+)\s*/\s*(\d+)\s*", text, problem)
        if not i < n:
            raise ValueError(problem)
        return i, n


class KeyValue(click.ParamType):
    """key=value, kept as given: `key_values` reads the repeated option (so that its errors, a
    missing '=' or a key given twice, are dc's one line naming the option, exit 2)."""
    name = "KEY=VALUE"

    def convert(self, value, param, ctx):
        return value


def key_values(given, option):
    """{key: value} of a repeatable KEY=VALUE option; OptionError naming `option` for an entry
    without '=' or a key given twice (which would silently take the last)."""
    from deepcontact.errors import OptionError
    out = {}
    for text in given:
        if isinstance(text, tuple):   # (already a pair: a caller in code)
            key, val = text
        else:
            key, sep, val = str(text).partition("=")
            key, val = key.strip(), val.strip()
            if not sep or not key:
                raise OptionError(f"takes KEY=VALUE, got {text!r}", option)
        if key in out:
            raise OptionError(f"{key} is given twice ({key}={out[key]} and {key}={val}); give it once", option)
        out[key] = val
    return out


def verbosity(f):
    f = click.option("-v", "--verbose", count=True, help="More output; -v also shows tracebacks.")(f)
    f = click.option("-q", "--quiet", count=True, help="Less output: no progress bar, warnings only.")(f)
    return f


def plots(what):
    """--plots/--no-plots, on by default: `what` says what is drawn and what --no-plots leaves."""
    return click.option("--plots/--no-plots", default=True, show_default=True, help=what)


overwrite = click.option("--overwrite", is_flag=True,
                         help="Replace existing output: the new output is built beside it and swapped in "
                         "only when complete, so a failed or interrupted run keeps the old one.")
threads = click.option("--threads", type=click.IntRange(min=1), default=1, show_default=True,
                       help="torch threads per process (prediction, training). More than one spins against other "
                       "processes, so on a busy machine times move by up to 100x; and the count changes the order "
                       "of float sums, so training takes 1 only (it repeats exactly; torchrun spreads it over "
                       "processes). Never the machine's cores; recorded in every report and checkpoint.")
jobs = click.option("-j", "--jobs", type=click.IntRange(min=1), default=1, show_default=True,
                    help="Worker processes.")


class ClosedStdout(io.TextIOBase):
    """What sys.stdout is when the shell closed it (`>&-`): writing data to it fails, in one line."""

    def writable(self):
        return True

    def write(self, text):
        import errno
        raise OSError(errno.EBADF, "standard output is closed: nothing to write this command's output to")


def stdout_is_open():
    return not isinstance(sys.stdout, ClosedStdout)


def require_stdout(alternative):
    """Refuses, before any work, a command whose only output would go to a closed stdout."""
    if not stdout_is_open():
        raise click.UsageError(f"standard output is closed, and it is where this output goes: {alternative}")


def show_output(text, quiet):
    """The line naming what a command wrote (stdout): not shown with -q, nor to a closed stdout
    (the output itself is complete; the line only says where it is)."""
    if not quiet and stdout_is_open():
        import os
        staged, shown = os.environ.get("DC_OUTPUT_STAGED"), os.environ.get("DC_OUTPUT_SHOWN")
        if staged and shown and "DC_SANDBOX_BROKER" in os.environ:   # (a fenced job: the user's path, not its stage)
            text = text.replace(staged, shown)
        click.echo(text)


def log_level(verbose, quiet):
    return max(logging.DEBUG, min(logging.ERROR, logging.INFO - 10 * verbose + 10 * quiet))


def setup_logging(verbose, quiet):
    logging.basicConfig(level=log_level(verbose, quiet), stream=sys.stderr,
                        format="%(levelname)s: %(message)s", force=True)   # (force: each command its own stderr)
    for noisy in ("matplotlib", "PIL"):   # their debug output is not ours
        logging.getLogger(noisy).setLevel(max(logging.WARNING, log_level(verbose, quiet)))
    # Python warnings of the libraries (matplotlib, torch, numpy) are advice to us, not to the
    # user, and span lines: into the log, shown with -v only.
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(logging.WARNING if verbose else logging.ERROR)


def command(name):
    """Wraps a subcommand body: logging set-up, InputError → one line and exit 1, Ctrl-C,
    SIGTERM and SIGHUP → clean-up and exit 128 + signal; tracebacks only with -v."""
    def decorate(f):
        @functools.wraps(f)
        def wrapper(*args, **kwargs):
            try:
                return run(*args, **kwargs)
            finally:   # (in-process callers, the tests: the next command starts afresh)
                interrupts.uninstall()

        def run(*args, verbose=0, quiet=0, **kwargs):
            setup_logging(verbose, quiet)
            _take_aliases(name, kwargs)
            interrupts.install(f"dc {name}")
            output.completed.clear()

            def fail(message):
                click.echo(one_line(f"dc {name}: error: {message}"), err=True)
                sys.exit(1)
            try:
                return f(*args, verbose=verbose, quiet=quiet, **kwargs)
            except SystemExit as e:   # not ours (a command ends with click's Exit): a library or a plug-in's
                if verbose:
                    raise
                fail(f"something the command ran called sys.exit({e.code!r}) (a plug-in?); -v shows where")
            except OptionError as e:
                if verbose:
                    raise
                click.echo(one_line(f"dc {name}: error: {e}"), err=True)
                sys.exit(2)
            except (InputError, Failure) as e:
                if verbose:
                    raise
                fail(e)
            except KeyboardInterrupt as e:
                if not interrupts.user_stopped():   # raised by code, not by a stop signal
                    if verbose:
                        raise
                    fail("something the command ran raised KeyboardInterrupt itself, with no stop signal "
                         "(a plug-in?); -v shows where")
                signum = e.signum if isinstance(e, Terminated) else signal.SIGINT
                if output.completed:   # the signal waited for a swap to finish
                    click.echo(f"dc {name}: interrupted ({signal.Signals(signum).name}) after its output was "
                               f"complete: {show_path(output.completed[-1])} is the new output", err=True)
                else:
                    click.echo(f"dc {name}: interrupted ({signal.Signals(signum).name}); no partial output was "
                               f"left, and output being replaced (--overwrite) is as it was", err=True)
                sys.exit(128 + signum)
            except MemoryError:
                if verbose:
                    raise
                fail(out_of_memory(kwargs))
            except OSError as e:
                if verbose:
                    raise
                where = f"{show_path(e.filename)}: " if getattr(e, "filename", None) else ""
                fail(f"{where}{e.strerror or e}")
            except (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort):
                raise
            except RecursionError:
                if verbose:
                    raise
                fail("the input is nested too deeply to read")
            except ImportError as e:   # (an optional module a plain pip install does not bring: how to get it)
                from deepcontact.errors import missing_module
                if verbose or missing_module(e) is None:
                    raise
                fail(missing_module(e))
            except Exception as e:   # a promise kept even where a check is missing: one line, no traceback
                if verbose:
                    raise
                if _out_of_memory(e):   # torch's ("DefaultCPUAllocator: can't allocate memory"), a RuntimeError
                    fail(out_of_memory(kwargs))
                fail(f"{type(e).__name__}: {e} (not a message of ours: please report it; -v shows where it came from)")
        return wrapper
    return decorate


def out_of_memory(kwargs):
    """The one line for an allocation that failed; with --threads above 1, the threads are named
    first (each holds buffers of its own), not the work."""
    threads = kwargs.get("threads") or 1
    return ("out of memory" + (f" with --threads {threads}: each thread holds buffers of its own, so try "
                               f"--threads 1 first; else" if threads > 1 else ";")
            + " lower the size of the work (or --max-memory to be refused earlier)")


def _out_of_memory(e):
    """Whether an exception (torch's RuntimeError, say) is an allocation that failed."""
    text = str(e).lower()
    return "can't allocate memory" in text or "out of memory" in text or "bad_alloc" in text


# Off a terminal (a log file, Make, CI, nohup, a cluster's batch job), a long run says where it is
# in one line at least this often: what is done, the rate, about how long is left
# (DC_PROGRESS_EVERY=SECONDS sets another period).
PROGRESS_EVERY = 30.0   # seconds


def progress_every():
    import os
    try:
        value = float(os.environ.get("DC_PROGRESS_EVERY", PROGRESS_EVERY))
    except ValueError:
        return PROGRESS_EVERY
    return value if value >= 0 else PROGRESS_EVERY


def progress_bar(quiet, total, unit, desc):
    """A tqdm bar on stderr when it is a terminal; elsewhere a line every PROGRESS_EVERY seconds
    (LineBar); nothing when quiet (every bar takes update() and close(), so callers need not ask
    which). Neither off-terminal bar is tqdm's: a command in a pipeline need not import it."""
    if quiet:
        return SilentBar()
    if not _is_terminal(sys.stderr):
        return LineBar(total, unit, desc)
    from tqdm import tqdm
    return tqdm(total=total, unit=unit, desc=desc, file=sys.stderr, dynamic_ncols=True, leave=False)


def _is_terminal(stream):
    try:
        return stream is not None and stream.isatty()
    except (OSError, ValueError):   # closed
        return False


class SilentBar:
    """What progress_bar gives when nothing is shown: counts, says nothing."""

    def __init__(self):
        self.n = 0

    def update(self, n=1):
        self.n += n

    def close(self):
        pass


class LineBar(SilentBar):
    """Progress off a terminal: a line on stderr at the first update PROGRESS_EVERY seconds after
    the last line (what is done, the rate, what is left), and one at the end of a run that wrote
    any; a short run says nothing."""

    def __init__(self, total, unit, desc):
        super().__init__()
        import time
        self.total, self.unit, self.desc = total, unit, desc
        self.started = self.said = time.monotonic()
        self.lines, self.every = 0, progress_every()

    def update(self, n=1):
        import time
        self.n += n
        now = time.monotonic()
        if now - self.said >= self.every:
            self.said = now
            self._say(now, done=False)

    def close(self):
        if self.lines:
            import time
            self._say(time.monotonic(), done=True)

    def _say(self, now, done):
        took = max(now - self.started, 1e-9)
        rate = self.n / took
        of = f"/{self.total:,}" if self.total else ""
        share = f" ({100 * self.n / self.total:.0f}%)" if self.total else ""
        left = ""
        if not done and self.total and rate > 0 and self.n < self.total:
            left = f", about {duration((self.total - self.n) / rate)} left"
        what = "so far" if not done else "done" if not self.total or self.n >= self.total else "when it ended"
        sys.stderr.write(f"dc {self.desc}: {self.n:,}{of} {self.unit}s{share} {what} in {duration(took)}, "
                         f"{rate:.3g} {self.unit}s/s{left}\n")
        sys.stderr.flush()
        self.lines += 1


def duration(seconds):
    """A time for a progress line: 42s, 3m05s, 2h10m."""
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds // 60 % 60:02d}m"


def pick_cases(cases, labels):
    """--scenes: the study's cases with these labels, in the order given (all of them without);
    a label it does not have is a bad option value (exit 2, listing the labels it has)."""
    if not labels:
        return cases
    known = {c.label: c for c in cases}
    unknown = [s for s in labels if s not in known]
    if unknown:
        raise click.BadParameter(f"no scene {unknown[0]!r} here; the scenes are: {', '.join(known)}",
                                 param_hint="--scenes")
    return [known[s] for s in labels]


def pick_families(known, names):
    """--families: these names, each one of the study's `known` families or one setting of one
    ('FAMILY:SETTING', checked by the study); all of them without. A family it does not have is a
    bad option value (exit 2, listing the families it has)."""
    unknown = [f for f in names or () if f.partition(":")[0] not in known]
    if unknown:
        raise click.BadParameter(f"no family {unknown[0]!r}; the families are: {', '.join(known)}",
                                 param_hint="--families")
    return tuple(names) if names else None


def families_option(example):
    """--families for a study whose settings come in families (the names in its tables)."""
    return click.option("--families", type=CommaList(click.STRING, "FAMILY[,...]"),
                        help=f"Only these families' settings, by their names in the tables (e.g. {example!r}); "
                             "FAMILY:SETTING picks one setting (e.g. 'pymunk:10 iterations').")


class SoftStepOption(click.Option):
    """An option of Box2D v3's soft step (--substeps, --contact-hertz, ...): its help states v3's
    own default, read from the library when the help is shown (simulate.engines.SoftStep)."""

    def get_help_record(self, ctx):
        from deepcontact.errors import InputError
        from deepcontact.simulate.engines import soft_step_defaults
        try:
            default = soft_step_defaults()[self.name]
        except InputError:   # (a build without v3: the option is refused when used)
            return super().get_help_record(ctx)
        plain = self.help
        self.help = f"{plain} (default {default:g}: Box2D v3's own)"
        try:
            return super().get_help_record(ctx)
        finally:
            self.help = plain


def solve_to_tolerance(f):
    """--tolerance, --max-iterations and --stop-on of a command that solves every step to a
    tolerance and compares its variants (dc evaluate), their defaults read from solver/settings.py
    (the cap: VERDICT_CAP, at which its variants reach the tolerance, so that a verdict can name one)."""
    from deepcontact.solver.settings import TOLERANCE, VERDICT_CAP as CAP
    for option in reversed((
            click.option("--tolerance", type=Finite(min=0, min_open=True), default=TOLERANCE, show_default=True,
                         help="Stop once the measure falls below this."),
            click.option("--max-iterations", type=count(min=1), default=CAP, show_default=True,
                         help="Sweep cap."),
            click.option("--stop-on", type=choice("stop_on"), default="residual", show_default=True,
                         help="The measure the tolerance applies to (docs/solver.md: Measuring convergence)."))):
        f = option(f)
    return f


max_memory = click.option("--max-memory", type=Finite(min=0, min_open=True), metavar="GB",
                          help="Refuse work estimated to need more memory than this (default 8).")


def check_grid_options(kernel, cell, smoothing):
    """--cell and --smoothing that no float32 grid can carry: a bad option value (exit 2)."""
    from deepcontact.grid.spec import node_weight_problem
    problem = node_weight_problem(kernel, cell, smoothing)
    if problem:
        raise click.BadParameter(problem, param_hint="'--cell' / '--smoothing'")


def refuse_inapplicable(rules):
    """One rule for every command: an option the user gave that does not apply to the chosen mode
    is refused (exit 2, naming it and why) rather than ignored. rules: (parameter name, whether it
    applies, why not). Defaults never count: only what was given (was_given)."""
    ctx = click.get_current_context()
    for name, applies, why in rules:
        if applies or not was_given(name):
            continue
        param = next(p for p in ctx.command.params if p.name == name)
        flag = max(param.opts, key=len)
        if getattr(param, "secondary_opts", None) and ctx.params.get(name) is False:
            flag = max(param.secondary_opts, key=len)
        raise click.UsageError(f"{flag} {why}")


def deprecated_alias(old, new, target):
    """A hidden option kept for an old spelling of the option whose parameter is `target`: given,
    it stands for that option (the command's wrapper puts its value there and says it is
    deprecated); given with the new spelling, it is refused."""
    def keep(ctx, param, value):
        if value is not None:
            ctx.meta.setdefault("dc_aliases", []).append((old, new, target, value))
        return value
    return click.option(old, f"{old.lstrip('-').replace('-', '_')}_alias", hidden=True, expose_value=False,
                        callback=keep, help=f"Deprecated: {new}.")


def _take_aliases(name, kwargs):
    """The deprecated spellings given, moved to the options they stand for (and said)."""
    from click.core import ParameterSource
    ctx = click.get_current_context()
    for old, new, target, value in ctx.meta.get("dc_aliases", []):
        if ctx.get_parameter_source(target) not in (ParameterSource.DEFAULT, ParameterSource.DEFAULT_MAP, None):
            raise click.UsageError(f"{old} is the old spelling of {new}: give one")
        logging.getLogger("deepcontact.cli").warning("%s is deprecated in dc %s: use %s", old, name, new)
        kwargs[target] = value
        ctx.meta.setdefault("dc_given", set()).add(target)


def was_given(name):
    """Whether the user gave the option whose parameter is `name` (typed, from the environment, or
    by a deprecated spelling), not left it at its default."""
    from click.core import ParameterSource
    ctx = click.get_current_context()
    return name in ctx.meta.get("dc_given", ()) or ctx.get_parameter_source(name) not in (
        None, ParameterSource.DEFAULT, ParameterSource.DEFAULT_MAP)


# The library table each choice option's words come from: (module, attribute).
VOCABULARIES = {
    "stop_on": ("deepcontact.solver.pgs", "MEASURES"),
    "mode": ("deepcontact.solver.pgs", "MODES"),
    "kernel": ("deepcontact.grid.kernels", "KERNELS"),
    "loss": ("deepcontact.model.choices", "LOSSES"),
    "optimizer": ("deepcontact.model.choices", "OPTIMIZERS"),
    "loop_start": ("deepcontact.simulate.pgs_loop", "STARTS"),
    "solution": ("deepcontact.exchange.fclib", "SOLUTIONS"),
}


def vocabulary(name):
    """A choice option's words, from the library table that owns them (one spelling everywhere)."""
    import importlib
    module, attribute = VOCABULARIES[name]
    return list(getattr(importlib.import_module(module), attribute))


def choice(name, leave_out=()):
    """click.Choice over vocabulary(name), less the words a command does not take."""
    return click.Choice([w for w in vocabulary(name) if w not in leave_out])


def plugin_methods(f):
    """--accelerate for a study: plug-in solver methods, a family each beside the built-in ones."""
    return click.option("--accelerate", "plugins", type=CommaList(click.STRING, "METHOD[,...]"), default=[],
                        help="Plug-in solver methods (an installed one's name, or package.module:Name), a family each "
                             "at the study's tolerances: each solve in the method's own process, timed and judged as "
                             "dc evaluate does (docs/api.md).")(f)


def described_methods(names):
    """The plug-in methods named for a study, described from a process of their own (their code is
    never imported here); a built-in name is refused (its family is the study's already)."""
    from deepcontact.contest import describe
    from deepcontact.solver.methods import is_native
    for name in names:
        if is_native(name):
            raise OptionError(f"{name} is a built-in method: the study's own families run it (--families)",
                              "--accelerate")
    describe(methods=list(names))
    return list(names)


def load_solvers(names):
    """--accelerate: plug-in solver methods loaded by the user's explicit choice (a method's rules
    against the other options are the SolveSettings' the command then makes)."""
    from deepcontact.solver.methods import SOLVERS, is_native
    for name in names:
        if not is_native(name):
            SOLVERS.load(name)


def load_network(arch):
    """--arch: a network plug-in loaded by the user's explicit choice (built-ins need nothing)."""
    if arch is not None:
        from deepcontact.model.arch import BUILTIN, NETWORKS
        if arch not in BUILTIN:
            NETWORKS.load(arch)
