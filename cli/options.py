"""Options and behaviour shared by every `dc` subcommand (rasterio style): -v/-q counted into
one log level, logs and progress on stderr, clean one-line errors unless -v."""
import functools
import logging
import os
import signal
import sys

import click
from click.core import ParameterSource

from deepcontact import interrupts, output
from deepcontact.contest import result
from deepcontact.errors import Failure, InputError, OptionError, StudyFailed, missing_module, one_line, show_path
from deepcontact.interrupts import Terminated

from .terminal import as_the_user_named_it, setup_logging
from .types import CommaList, Finite, PluginName, choice, count


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


def command(name):
    """Wraps a subcommand body: logging set-up, InputError → one line and exit 1, Ctrl-C,
    SIGTERM and SIGHUP → clean-up and exit 128 + signal; tracebacks only with -v."""
    def decorate(f):
        @functools.wraps(f)
        def wrapper(*args, **kwargs):
            try:
                return run(*args, **kwargs)
            finally:   # (in-process callers, the tests: the next command starts afresh)
                _say_what_ran_bare(name)
                interrupts.uninstall()

        def run(*args, verbose=0, quiet=0, **kwargs):
            setup_logging(verbose, quiet)
            _take_aliases(name, kwargs)
            interrupts.install(f"dc {name}")
            output.completed.clear()
            if "deepcontact.contest.sandbox" in sys.modules:   # (in-process callers: what an earlier one ran bare)
                sys.modules["deepcontact.contest.sandbox"].ran_bare.clear()
            output.record.remarks.clear()
            try:
                done = f(*args, verbose=verbose, quiet=quiet, **kwargs)
            except BaseException as e:
                ended = _ending(name, e, verbose, kwargs)
                _say_how_it_ended(e, ended)
                if ended is None:
                    raise
                code, line = ended
                click.echo(as_the_user_named_it(line), err=True)
                sys.exit(code)
            result.say(result.IN_ORDER, 0)
            return done
        wrapper.dc_command = True   # (cli/study.py: a command held already)
        return wrapper
    return decorate


# --unfenced: plug-in code may run without its sandbox where this machine cannot build one (it
# fails closed otherwise: contest/sandbox.py, refuse_bare); the command's last line says what ran bare.
_UNFENCED_HELP = ("Run plug-in code bare where this machine cannot build its sandbox (no bubblewrap, user "
                  "namespaces or control group); without it such a run is refused. The last line names what "
                  "was missing.")


def allow_unfenced(ctx, param=None, value=True):
    """--unfenced's callback: plug-in code may run bare for the rest of the command ctx."""
    if value:
        from deepcontact.contest import sandbox
        os.environ[sandbox.UNFENCED_ENV] = "1"
        ctx.call_on_close(lambda: os.environ.pop(sandbox.UNFENCED_ENV, None))


def unfenced(f):
    return click.option("--unfenced", is_flag=True, expose_value=False, callback=allow_unfenced, is_eager=True,
                        help=_UNFENCED_HELP)(f)   # (eager: before --help, which lists plug-in studies)


def _say_what_ran_bare(name):
    box = sys.modules.get("deepcontact.contest.sandbox")   # (not loaded: nothing was fenced, nor ran bare)
    if box is not None and box.ran_bare:
        click.echo(f"dc {name}: plug-in code ran without its sandbox, as --unfenced allowed (missing here: "
                   f"{', '.join(sorted(box.ran_bare))})", err=True)
        box.ran_bare.clear()


def _say_how_it_ended(e, ended):
    """The fenced command's record (contest/result.py) for a command that raised e: in order for
    click's Exit and a study whose verdict is a failure, failed for the rest (a traceback with -v
    included); nothing where no fence asked for one."""
    if isinstance(e, click.exceptions.Exit):
        result.say(result.IN_ORDER, e.exit_code)
    elif isinstance(e, click.exceptions.ClickException):   # (a bad option found by the command: click's exit 2)
        result.say(result.FAILED, e.exit_code, e.format_message())
    elif isinstance(e, StudyFailed):   # (its table is written: a verdict, not a failure to run)
        result.say(result.IN_ORDER, 1, str(e))
    else:
        result.say(result.FAILED, ended[0] if ended is not None else 1, ended[1] if ended is not None else repr(e))


_CLICKS = (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort)


def _ending(name, e, verbose, kwargs):
    """(exit code, the line on stderr) a command ends with for the exception e, or None where e
    is raised as it is: click's own, and with -v every other (for its traceback)."""
    if isinstance(e, _CLICKS):
        return None
    if isinstance(e, KeyboardInterrupt) and interrupts.user_stopped():
        return _interrupted(name, e)
    if verbose:
        return None
    if isinstance(e, OptionError):
        return 2, one_line(f"dc {name}: error: {e}")
    message = _message(e, kwargs)
    return None if message is None else (1, one_line(f"dc {name}: error: {message}"))


def _interrupted(name, e):
    """Exit 128 + the signal, and whether the output had been swapped in when it came."""
    signum = e.signum if isinstance(e, Terminated) else signal.SIGINT
    if output.completed:   # the signal waited for a swap to finish
        line = (f"dc {name}: interrupted ({signal.Signals(signum).name}) after its output was complete: "
                f"{show_path(output.completed[-1])} is the new output")
    else:
        line = (f"dc {name}: interrupted ({signal.Signals(signum).name}); no partial output was left, and output "
                f"being replaced (--overwrite) is as it was")
    return 128 + signum, line


def _message(e, kwargs):
    """The one line saying what ended a command (exit 1), or None: raised as it is. A promise
    kept even where a check is missing: whatever a command or its plug-ins raise is one line."""
    if isinstance(e, SystemExit):   # not ours (a command ends with click's Exit): a library or a plug-in's
        return f"something the command ran called sys.exit({e.code!r}) (a plug-in?); -v shows where"
    if isinstance(e, (InputError, Failure)):
        return e
    if isinstance(e, KeyboardInterrupt):   # raised by code, not by a stop signal
        return ("something the command ran raised KeyboardInterrupt itself, with no stop signal (a plug-in?); "
                "-v shows where")
    if isinstance(e, MemoryError):
        return out_of_memory(kwargs)
    if isinstance(e, OSError):
        where = f"{show_path(e.filename)}: " if getattr(e, "filename", None) else ""
        return f"{where}{e.strerror or e}"
    if isinstance(e, RecursionError):
        return "the input is nested too deeply to read"
    if isinstance(e, ImportError):   # (an optional module a plain pip install does not bring: how to get it)
        return missing_module(e)
    if isinstance(e, Exception):
        if _out_of_memory(e):   # torch's ("DefaultCPUAllocator: can't allocate memory"), a RuntimeError
            return out_of_memory(kwargs)
        return f"{type(e).__name__}: {e} (not a message of ours: please report it; -v shows where it came from)"
    return None


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


def checkpoint(what, arch_help="Load this network plug-in for a checkpoint that needs it."):
    """--checkpoint FILE (parameter `model`; its old spelling --model kept) and --arch, a network
    plug-in the checkpoint needs: `what` says what the checkpoint is used for."""
    from deepcontact.model.arch import NETWORKS

    def decorate(f):
        for option in reversed((
                click.option("--checkpoint", "model", type=click.Path(dir_okay=False), help=what),
                deprecated_alias("--model", "--checkpoint", "model"),
                click.option("--arch", type=PluginName(NETWORKS), help=arch_help))):
            f = option(f)
        return f
    return decorate


def solve_to_tolerance(f):
    """--tolerance, --max-iterations and --stop-on of a command that solves every step to a
    tolerance and compares its variants (dc evaluate), their defaults read from solver/settings.py
    (the cap: VERDICT_CAP, at which its variants reach the tolerance, so that a verdict can name one)."""
    from deepcontact.solver import pgs, settings
    for option in reversed((
            click.option("--tolerance", type=Finite(min=0, min_open=True), default=settings.TOLERANCE,
                         show_default=True, help="Stop once the measure falls below this."),
            click.option("--max-iterations", type=count(min=1), default=settings.VERDICT_CAP, show_default=True,
                         help="Sweep cap."),
            click.option("--stop-on", type=choice(pgs.MEASURES), default="residual", show_default=True,
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
    ctx = click.get_current_context()
    return name in ctx.meta.get("dc_given", ()) or ctx.get_parameter_source(name) not in (
        None, ParameterSource.DEFAULT, ParameterSource.DEFAULT_MAP)


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
