"""Registries: one per kind of thing a researcher brings (warm starts, networks), used by the
built-ins themselves. A name resolves to a registered built-in, to an entry point of an installed
package (groups ``deepcontact.starts``, ``deepcontact.networks``), or, written
``package.module:Name``, to that attribute of an importable module. Loading a plug-in is always the user's explicit choice (a name on the command
line or in code); nothing read from a file ever imports code.
"""
import importlib
import re
from contextlib import contextmanager

from . import interrupts, protocol
from .errors import InputError

_NAME = re.compile(r"[a-z][a-z0-9-]*")
_TARGET = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_][\w.]*")


class PluginError(InputError):
    """A plug-in that cannot be found, imported or used: one line naming it and what is wrong."""


# True in a contestant's own process (deepcontact.contest): the process is the plug-in's guard
# there (nothing it changes reaches the judge), so guest() only turns what leaves its code into one
# line, and no copy of a step is made for it (unpickled for each call, it is its own already).
contained = False


class _GuestExit(BaseException):
    """os._exit called by a plug-in: raised in its code instead, as sys.exit's SystemExit is."""


def _refuse_exit(code):
    raise _GuestExit(code)


@contextmanager
def guest(what, doing="raised"):
    """Runs a plug-in's code (`what` names it: "the start 'x'"). Whatever leaves it becomes one
    PluginError, "{what} {doing} {Type}: {message}", chained to the original (so -v shows its file
    and line): an exception, sys.exit() or os._exit() (which would end dc with its partial output
    and lock left, exit 0), a KeyboardInterrupt it raised itself (the user's own stop passes
    through). A process it forked never comes back out into dc's code (it would run the rest of
    the command): it ends there. As it returns, the signal handlers, the working folder, the
    umask and torch's thread count it changed are put back, and a stop signal it swallowed is
    raised."""
    import os
    import sys
    from contextlib import nullcontext
    # (in a contestant's process, what it changes there reaches nothing of dc's: nothing to put back)
    keep = not contained
    cwd, mask, threads = None, None, None
    if keep:
        try:
            cwd = os.getcwd()
        except OSError:
            pass
        from .output.files import umask   # (not at the top: a contestant, which keeps nothing, never loads it)
        mask = umask()
        threads = sys.modules["torch"].get_num_threads() if "torch" in sys.modules else None
    pid, outermost = os.getpid(), os._exit is not _refuse_exit
    if outermost:
        os._exit = _refuse_exit
    try:
        try:
            with interrupts.guest_code() if keep else nullcontext():
                yield
        finally:
            if os.getpid() != pid:   # a child the plug-in forked, coming back out: it ends here, said
                _forked_child_ends(what)
            if outermost:
                os._exit = interrupts.real_exit
    except _GuestExit as e:
        raise PluginError(f"{what} called os._exit({e.args[0]!r}): a plug-in cannot end the command") from None
    except InputError:   # ours already (a PluginError, or a check the plug-in called)
        raise
    except KeyboardInterrupt as e:
        if interrupts.user_stopped():
            raise
        raise PluginError(f"{what} raised KeyboardInterrupt itself (no stop signal came)") from e
    except SystemExit as e:
        raise PluginError(f"{what} called sys.exit({e.code!r}): a plug-in cannot end the command") from e
    except BaseException as e:   # (GeneratorExit and the like as well: nothing of a guest's passes as ours)
        raise PluginError(f"{what} {doing} {type(e).__name__}: {e}") from e
    finally:
        if keep:
            _put_back(cwd, mask, threads)
    interrupts.check()


def _forked_child_ends(what):
    """In a process the plug-in forked that carried on out of its code (it would run the rest of
    the command: a second report, a second swap): one line on standard error naming the plug-in,
    then the process ends, running nothing of dc's (no handler, no flush of what the parent holds)."""
    import os
    line = f"dc: {what} forked a process that carried on out of its code: it was ended there, running nothing of dc's\n"
    try:
        os.write(2, line.encode(errors="backslashreplace"))
    except OSError:   # (standard error closed: ended all the same)
        pass
    interrupts.real_exit(0)


def _put_back(cwd, mask, threads):
    """The process state a guest may have changed, put back: the working folder, the umask the
    outputs' modes come from, torch's thread count (--threads; the count changes float sums and
    times)."""
    import os
    if cwd is not None:
        try:
            if os.getcwd() != cwd:
                os.chdir(cwd)
        except OSError:
            os.chdir(cwd)
    os.umask(mask)
    protocol.keep_threads(threads)


class Registry:
    """Named factories of one kind. `register` adds a built-in (or a plug-in registering itself in
    code); `load` resolves a name as described in the module docstring."""

    def __init__(self, kind, group):
        self.kind, self.group = kind, group
        self._builtin = {}
        self._loaded = {}   # plug-ins loaded by an explicit choice (load), by name
        # plug-ins described from a process of their own (contest.describe), by name:
        # what a judge may know of them without importing their code
        self.described = {}
        self._chosen = set()   # names the user chose (a command's --arch) without their code imported: choose

    def register(self, name, factory=None, **traits):
        """Registers factory under name (lower case, digits and '-'); usable as a decorator.
        factory may be "package.module:Name", imported when first used (a built-in whose module
        needs what its registry must not import, torch say). traits: what the rest of the
        pipeline may ask of it (see the kind's contract)."""
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise PluginError(f"a {self.kind} name is lower case letters, digits and '-': {name!r}")

        def add(f):
            if not (callable(f) or isinstance(f, str) and _TARGET.fullmatch(f)):
                raise PluginError(f"the {self.kind} {name!r} must be registered as a class or function (or "
                                  f"'package.module:Name'), got {type(f).__name__}")
            if not isinstance(f, str):
                for key, value in traits.items():
                    setattr(f, key, value)
            self._builtin[name] = f
            return f
        return add if factory is None else add(factory)

    def origin(self, name):
        """Where the thing named `name` comes from, for the record (manifests, reports):
        {"origin": "built-in" or "plug-in", "target": "module:Name", and for a plug-in from an
        installed package its "distribution" and "version"}. Nothing is imported for it: a name
        not loaded yet is {"origin": "not loaded"}."""
        factory = self.resolved(name)
        if factory is None and name in self.described:
            return dict(self.described[name]["origin"])
        if factory is None:
            return {"origin": "not loaded", "name": name}
        module = getattr(factory, "__module__", None) or ""
        target = f"{module}:{getattr(factory, '__qualname__', getattr(factory, '__name__', '?'))}"
        if module == "deepcontact" or module.startswith("deepcontact."):
            return {"origin": "built-in", "name": name, "target": target}
        out = {"origin": "plug-in", "name": name, "target": target, "distribution": None, "version": None}
        try:
            from importlib.metadata import packages_distributions, version
            dists = packages_distributions().get(module.split(".")[0]) or []
            if dists:
                out["distribution"], out["version"] = dists[0], version(dists[0])
        except Exception:   # (metadata that cannot be read says nothing of the plug-in itself)
            pass
        return out

    def choose(self, name):
        """Records `name` as the user's explicit choice (a command's --arch) without importing it:
        a checkpoint naming it may then be read, and its code is loaded where it runs (a
        contestant's sandbox), never here."""
        self._chosen.add(name)

    def chosen(self, name):
        """Whether `name` is a built-in, loaded, or chosen by the user (choose)."""
        return name in self._builtin or name in self._loaded or name in self._chosen

    def builtin(self):
        """The names registered in code, in registration order."""
        return list(self._builtin)

    def installed(self):
        """{name: entry point} of the installed packages' plug-ins of this kind, each name of the
        form a registered one has (lower case letters, digits and '-'): a name with '+' or '@'
        reads as a variant's label ('builtin+peek': builtin with the method 'peek'), so an
        installed oracle so named was taken for builtin, no oracle. One of another form is none."""
        from importlib.metadata import entry_points   # (scans every installed package: only when asked)
        return {ep.name: ep for ep in entry_points(group=self.group) if _NAME.fullmatch(ep.name)}

    def names(self):
        return self.builtin() + [n for n in self.installed() if n not in self._builtin]

    def is_name(self, text):
        """Whether text could name one of these (a registered name or a module:attribute)."""
        return text in self._builtin or text in self.installed() or bool(_TARGET.fullmatch(text))

    def load(self, name):
        """The factory named `name`; PluginError naming it if it cannot be had."""
        if name in self._builtin:
            return self._builtin_factory(name)
        if name in self._loaded:   # (loaded once: the scan of installed packages costs ~10 ms)
            return self._loaded[name]
        found = self.installed().get(name)
        if found is None and not _TARGET.fullmatch(name):
            raise PluginError(f"unknown {self.kind} {name!r}: choose from {', '.join(self.names())}, or name one "
                              f"as package.module:Name")
        target = found.value if found is not None else name
        module, _, attribute = target.partition(":")
        with guest(f"the {self.kind} plug-in {name!r}", f"cannot be loaded ({target}):"):
            obj = importlib.import_module(module)
            for part in attribute.split("."):
                obj = getattr(obj, part)
        if not callable(obj):
            raise PluginError(f"the {self.kind} plug-in {name!r} ({target}) is not a class or function")
        self._loaded[name] = obj
        return obj

    def resolved(self, name):
        """The factory of a built-in or of a plug-in already loaded by an explicit choice (load),
        or None: what a name read from a file may resolve to, so that a file never imports code."""
        return self._builtin_factory(name) if name in self._builtin else self._loaded.get(name)

    def _builtin_factory(self, name):
        f = self._builtin[name]
        if isinstance(f, str):   # a built-in named by its place: imported now, once
            module, _, attribute = f.partition(":")
            f = self._builtin[name] = getattr(importlib.import_module(module), attribute)
        return f
