"""The types of dc's options (click parameter types): finite numbers, counts, lists, seeds,
shards, windows, plug-in names, KEY=VALUE pairs and the choices whose words the library owns."""
import math
import re

import click

from deepcontact.errors import OptionError
from deepcontact.solver.relaxation import parse_relaxation


class Finite(click.FloatRange):
    """A float option that must be finite (click's own ranges let nan and inf through)."""
    name = "finite float"

    def convert(self, value, param, ctx):
        value = super().convert(value, param, ctx)
        if not math.isfinite(value):
            self.fail(f"{value} is not a finite number", param, ctx)
        return value


INT32_MAX = 2 ** 31 - 1   # iteration and step counts: what Box2D and the native solver take


def count(min=0, max=INT32_MAX):
    """A whole-number option within what the native code takes."""
    return click.IntRange(min=min, max=max)


class OneSeed(click.IntRange):
    """One seed; a range or list given to it is pointed to the option that takes several
    (`--seed 0..1` read as "not a valid integer range" and left the user to find --seeds)."""

    def __init__(self, several):
        super().__init__(min=0, max=INT32_MAX)
        self.several = several

    def convert(self, value, param, ctx):
        if isinstance(value, str) and re.fullmatch(r"\s*\d+\s*\.\.\s*\d+\s*", value):
            self.fail(f"{value!r} is several seeds, and --seed takes one: use {self.several} {value.strip()}",
                      param, ctx)
        return super().convert(value, param, ctx)


class Relaxation(click.ParamType):
    """Over-relaxation: a w in (0, 2), or auto (chosen per scene from its first steps)."""
    name = "w|auto"

    def convert(self, value, param, ctx):
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


def choice(words, leave_out=()):
    """click.Choice over `words`, the library table that owns them (one spelling everywhere), less
    the words a command does not take."""
    return click.Choice([w for w in words if w not in leave_out])
