"""The one checker of what a contestant, or a fenced job, sends the judge: every message is
bounded in bytes before it is parsed, parsed by jsontext (refused past its depth), and held to
its kind's form before any of it is used. A form declares each field's type and bounds (how
long a text, how many entries a list or an object, how deep a value nests), so no message is
deeper or larger than its form allows, whatever it holds. FORMS is the table of every kind's
form: a contestant's answer (its header, with a plug-in engine's step layout) and a fenced job's
request to the broker; the descriptions of plug-ins are declared there too (`declare`), by the
code that reads them.

A message not of its form raises ShapeError, whose text names the field (`stats['a']`,
`layout['bodies.x'][1]`) and what it should be; the judge's side turns it into one line naming
the contestant (wire.unpack) or refuses the job's request naming the field (broker.Broker).
"""
import math

from .. import jsontext

WHOLE_MOST = 2 ** 63 - 1   # a whole number a message may hold (an int64: what numpy and a step file hold)
KEY_MOST = 1000            # characters of an object's key (a field, a setting, a plug-in's name)
NAMES_MOST = 64            # names (or modules, or files) a job's grant may list
DTYPES = ("bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float32", "float64")


class ShapeError(ValueError):
    """A message that is not of its form: the text names the field and what it should be."""


def _refused(at, value, should):
    shown = repr(value)
    shown = shown if len(shown) <= 60 else shown[:57] + "..."
    return ShapeError(f"the field {at or '(the whole message)'} is {shown}, not {should}")


def _number(value):
    """Whether value is a JSON number (not a flag) within what a message may hold."""
    if type(value) is int:
        return abs(value) <= WHOLE_MOST
    return type(value) is float and math.isfinite(value)


class Whole:
    """A whole number from `lowest` to `most` (a flag is no number here)."""

    def __init__(self, lowest=0, most=WHOLE_MOST):
        self.lowest, self.most = lowest, most

    def check(self, value, at):
        if type(value) is not int or not self.lowest <= value <= self.most:
            raise _refused(at, value, f"a whole number from {self.lowest} to {self.most}")
        return value


class Number:
    """A finite number from `lowest`."""

    def __init__(self, lowest=0.0):
        self.lowest = lowest

    def check(self, value, at):
        if not _number(value) or value < self.lowest:
            raise _refused(at, value, f"a finite number >= {self.lowest:g}")
        return value


class Flag:
    """true or false."""

    def check(self, value, at):
        if type(value) is not bool:
            raise _refused(at, value, "true or false")
        return value


class Text:
    """A string of at most `most` characters (one of `choices`, where given)."""

    def __init__(self, most=KEY_MOST, choices=None):
        self.most, self.choices = most, choices

    def check(self, value, at):
        if self.choices is not None and not (isinstance(value, str) and value in self.choices):
            raise _refused(at, value, "one of " + ", ".join(self.choices))
        if not isinstance(value, str) or len(value) > self.most:
            raise _refused(at, value, f"text of at most {self.most:,} characters")
        return value


class Scalar:
    """A value of one's own account: text (at most `most` characters), a flag or a finite number."""

    def __init__(self, most=KEY_MOST):
        self.most = most

    def check(self, value, at):
        if not (type(value) is bool or _number(value) or (isinstance(value, str) and len(value) <= self.most)):
            raise _refused(at, value, f"text of at most {self.most:,} characters, a flag or a finite number")
        return value


class Maybe:
    """null, or a value of the form `of` (a plug-in's distribution where it comes from none)."""

    def __init__(self, of):
        self.of = of

    def check(self, value, at):
        return value if value is None else self.of.check(value, at)


class Listing:
    """A list of at most `most` values of the form `of`."""

    def __init__(self, of, most):
        self.of, self.most = of, most

    def check(self, value, at):
        if not isinstance(value, list) or len(value) > self.most:
            raise _refused(at, value, f"a list of at most {self.most:,} entries")
        for i, item in enumerate(value):
            self.of.check(item, f"{at}[{i}]")
        return value


class Items:
    """A list of exactly these forms, in order (a pair: [dtype, shape])."""

    def __init__(self, *forms):
        self.forms = forms

    def check(self, value, at):
        if not isinstance(value, list) or len(value) != len(self.forms):
            raise _refused(at, value, f"a list of {len(self.forms)} entries")
        for i, (form, item) in enumerate(zip(self.forms, value)):
            form.check(item, f"{at}[{i}]")
        return value


class Table:
    """An object of at most `most` entries, each key text (KEY_MOST) and each value of the form `of`."""

    def __init__(self, of, most):
        self.of, self.most = of, most

    def check(self, value, at):
        if not isinstance(value, dict) or len(value) > self.most:
            raise _refused(at, value, f"an object of at most {self.most:,} entries")
        for key, item in value.items():
            if not isinstance(key, str) or len(key) > KEY_MOST:
                raise _refused(at, key, f"a key of text of at most {KEY_MOST} characters")
            self.of.check(item, f"{at}[{key!r}]")
        return value


class Record:
    """An object of the declared fields only (`fields`: name -> form), `required` among them."""

    def __init__(self, fields, required=()):
        self.fields, self.required = fields, tuple(required)

    def check(self, value, at):
        if not isinstance(value, dict):
            raise _refused(at, value, "an object")
        for key in self.required:
            if key not in value:
                raise ShapeError(f"the field {_joined(at, key)} is missing")
        for key, item in value.items():
            if key not in self.fields:
                raise ShapeError(f"{_joined(at, key[:KEY_MOST])!r} is not a field {at or 'it'} may hold")
            self.fields[key].check(item, _joined(at, key))
        return value


def _joined(at, key):
    return f"{at}.{key}" if at else key


class Data:
    """Any JSON value nested at most `depth` levels (a form not declared in detail yet: its bound)."""

    def __init__(self, depth):
        self.depth = depth

    def check(self, value, at):
        if jsontext.deeper(value, self.depth):
            raise _refused(at, value, f"a value nested at most {self.depth} levels")
        return value


class Declared:
    """The form declared in FORMS under `kind`, looked up when a message is checked (the hook by
    which the code that reads a description declares its form: `declare`)."""

    def __init__(self, kind):
        self.kind = kind

    def check(self, value, at):
        return FORMS[self.kind].check(value, at)


def declare(kind, form):
    """Declares (or replaces) the form of the message kind `kind` (FORMS), for every check after."""
    FORMS[kind] = form


def checked(value, kind, at=""):
    """value (parsed JSON) held to the form of `kind` (FORMS); ShapeError naming the field."""
    return FORMS[kind].check(value, at)


def parsed(data, kind, most, **kwargs):
    """The message `data` (bytes of JSON) of the kind `kind`: at most `most` bytes, parsed (no
    NaN, no Infinity), nested no deeper than jsontext allows and held to its form; ShapeError
    saying what is wrong (the field, where it is one)."""
    if len(data) > most:
        raise ShapeError(f"it is {len(data):,} bytes, more than the {most:,} a message of its kind may take")
    try:
        value = jsontext.loads(data, parse_constant=_no_constant, **kwargs)
    except ShapeError:
        raise
    except ValueError as e:
        raise ShapeError(str(e)) from None
    return checked(value, kind)


def _no_constant(name):
    raise ShapeError(f"{name} is not a number JSON allows")


# --- Every kind's form --------------------------------------------------------------------------

ERROR_MOST = 1 << 13       # characters of a contestant's error line (a line is cut at 600 when said)
TRACEBACK_MOST = 1 << 15   # characters of its traceback (the innermost frames: what -v shows)

# A plug-in engine's step: each array's dtype and shape, by its table's field ("bodies.x").
LAYOUT = Table(Items(Text(choices=DTYPES), Listing(Whole(), most=4)), most=256)

# An answer's header: every field it may hold. Descriptions (a start's traits, the plug-ins
# described, an engine's description) are declared by the code that reads them (Declared).
ANSWER = Record({
    "arrays": Listing(Items(Text(), Whole()), most=256),
    "iterations": Whole(), "fallback": Whole(), "factorizations": Whole(), "ready": Whole(), "built": Whole(),
    "seconds": Table(Number(), most=256),
    "error": Text(most=ERROR_MOST), "traceback": Text(most=TRACEBACK_MOST),
    "layout": Declared("engine layout"), "stats": Table(Scalar(most=1 << 16), most=1024),
    "dt_ratio": Number(), "deepest": Number(), "seq": Whole(),
    "traits": Declared("traits"), "described": Declared("plug-ins described"),
    "engine": Declared("engine described"),
}, required=("arrays",))

_NAMES = Listing(Text(), most=NAMES_MOST)

# A fenced job's request to the broker (contest/broker.py): what a contestant it asks for runs.
BROKER_REQUEST = Record({
    "op": Text(choices=("fences", "start", "cpu", "processes", "poll", "kill")),
    "id": Whole(1), "torch": Flag(), "threads": Whole(1),
    "grant": Record({"names": _NAMES, "modules": _NAMES, "files": _NAMES}, required=("names", "modules", "files")),
}, required=("op",))

FORMS = {
    "answer": ANSWER,
    "engine layout": LAYOUT,
    "broker request": BROKER_REQUEST,
    # (until their readers declare them in detail: objects, bounded in entries and depth)
    "traits": Table(Data(4), most=64),
    "plug-ins described": Table(Data(6), most=NAMES_MOST * 2),
    "engine described": Table(Data(4), most=64),
}
