"""The reference step-file reader: lxml, a tree and one XPath query per column, the names from
the table the writer and the native reader use (native/step_names.hpp, exported by the module).

Slow (10-60 times simulating and writing a step) and kept for that reason: it is independent of
the native streaming reader (deepcontact/native/step_read.cpp, behind step.reader), which the
tests hold to it value for value on every kind of step file. Every value is checked to be
present and finite, and a problem is an InputError naming the file (and line).
"""
import numpy as np

from .. import schema
from .._box2d import STEP_BODY_XML, STEP_CONTACT_XML
from ..errors import InputError, show_path
from .engines import rows_of

INT32_MAX = 2 ** 31 - 1   # every count and index in a step file (schemas/common.xsd: count)


def _fields(rows):
    """{field: (element, attributes by component, dtype, names or None, presence)} from the step
    file's names (native/step_names.hpp, the table the writer and the native reader use too)."""
    out = {}
    for element, attr, field, component, presence, names, dtype, width in rows:
        entry = out.setdefault(field, (element, [None] * width, np.dtype(dtype), names, presence))
        entry[1][component] = attr
    return {field: (e, tuple(attrs), dtype, names, presence) for field, (e, attrs, dtype, names, presence) in out.items()}


_BODY = _fields(STEP_BODY_XML)
_CONTACT = _fields(STEP_CONTACT_XML)
# what rasterizing needs of a step
_BODY_GRID = ("center", "velocity", "mass", "omega", "type")
_CONTACT_GRID = ("position", "normal", "normal_impulse", "tangent_impulse")


def _parse(path, validate):
    from lxml import etree
    if validate:
        _, tree, errors = schema.validate(path, "step")
        if errors:
            line, _, message = errors[0][len(show_path(path)) + 1:].split(":", 2)   # path:line:col: message
            raise InputError(message.strip(), path, int(line) if line.isdigit() else None)
    else:
        try:
            tree = schema.parse(path)
        except etree.XMLSyntaxError as e:
            raise InputError(f"not a well-formed step file: {e.msg}", path, e.lineno) from None
        except OSError as e:
            raise InputError(f"cannot read: {e.strerror or e}", path) from None
        if schema.has_doctype(tree):
            raise InputError(schema.DOCTYPE_REFUSED, path, 1)
    root = tree.getroot()
    if root.tag != "step":
        raise InputError(f"root element is <{root.tag}>, not <step>", path, root.sourceline)
    return root


def _count(element, attr, path, low=0, high=INT32_MAX):
    """An integer attribute within [low, high]; InputError naming the file and line otherwise."""
    text = element.get(attr)
    try:
        value = int(text)
    except (TypeError, ValueError):
        raise InputError(f"<{element.tag} {attr}> must be a whole number, got {text!r}", path,
                         element.sourceline) from None
    if not low <= value <= high:
        raise InputError(f"<{element.tag} {attr}> must be between {low} and {high}, got {value}", path,
                         element.sourceline)
    return value


def _child(element, tag, path):
    found = element.find(tag)
    if found is None:
        raise InputError(f"<{element.tag}> has no <{tag}>", path, element.sourceline)
    return found


def _float(element, attr, path):
    """A finite float32 attribute; InputError naming the file and line otherwise."""
    text = element.get(attr)
    try:
        value = np.float32(text)
    except (TypeError, ValueError):
        raise InputError(f"<{element.tag} {attr}> must be a number, got {text!r}", path, element.sourceline) from None
    if not np.isfinite(value):
        raise InputError(f"<{element.tag} {attr}> must be finite, got {text!r}", path, element.sourceline)
    return value


class _Columns:
    """Attribute columns of every `parent/child` element of a step file."""

    def __init__(self, root, path, parent, child):
        self.root, self.path, self.base = root, path, f"{parent}/{child}"
        self.child = child
        self.n = len(root.xpath(self.base))
        holder = root.find(parent)
        if holder is None:
            raise InputError(f"no <{parent}> element", path, root.sourceline)
        if _count(holder, "count", path) != self.n:
            raise InputError(f'<{parent} count="{holder.get("count")}"> but it holds {self.n} <{child}> elements',
                             path, holder.sourceline)

    def text(self, element, attr):
        where = self.base if element == "." else f"{self.base}/{element}"
        values = self.root.xpath(f"{where}/@{attr}")
        if len(values) != self.n:
            raise InputError(f"{self.n - len(values)} <{self.child}> element(s) lack <{self._name(element)} {attr}=...>",
                             self.path)
        return values

    def floats(self, element, attrs):
        cols = []
        for a in attrs:
            try:
                cols.append(np.array(self.text(element, a), dtype=np.float32))
            except ValueError:
                raise InputError(f"a <{element} {a}> value is not a number", self.path) from None
        arr = np.stack(cols, axis=1) if len(cols) > 1 else cols[0]
        if self.n == 0:
            return arr
        bad = ~np.isfinite(arr).reshape(self.n, -1).all(axis=1)
        if np.any(bad):
            k = int(np.argmax(bad))
            raise InputError(f"<{element}> of {self.child} {k} is not finite", self.path,
                             self.root.xpath(self.base)[k].sourceline)
        return arr

    def ints(self, element, attr, dtype):
        try:   # through int64, checked at once, then to the column's own type
            values = np.array([int(v) for v in self.text(element, attr)], dtype=np.int64)
        except ValueError:
            raise InputError(f"a <{self._name(element)} {attr}> value is not an integer", self.path) from None
        except OverflowError:
            values = None
        info = np.iinfo(dtype)
        low, high = max(info.min, 0), min(info.max, INT32_MAX) if dtype != np.uint32 else info.max
        bad = None if values is None else (values < low) | (values > high)
        if bad is None or bad.any():
            shown = "beyond 64 bits" if bad is None else int(values[np.argmax(bad)])
            raise InputError(f"a <{self._name(element)} {attr}> value is out of range ({shown}; {low} to {high})",
                             self.path)
        return values.astype(dtype)

    def _name(self, element):
        return self.child if element == "." else element

    def read(self, fields, only=None, engine="box2d"):
        """The columns of every field (or of those named in `only`) a file of this engine must
        hold for each row."""
        out = {}
        for field, (element, attrs, dtype, names, presence) in fields.items():
            if presence not in ("always", engine) or (only is not None and field not in only):
                continue
            if names is not None:
                out[field] = self.named(element, attrs[0], names)
            elif dtype.kind == "f":
                out[field] = self.floats(element, attrs)
            else:
                out[field] = self.ints(element, attrs[0], dtype)
        return out

    def named(self, element, attr, names):
        values = np.array([names.index(v) if v in names else -1 for v in self.text(element, attr)], dtype=np.int8)
        if np.any(values < 0):
            raise InputError(f"a <{self._name(element)} {attr}> is not one of {', '.join(names)}", self.path)
        return values

    def optional(self, fields, key, engine="box2d"):
        """The columns of the fields whose elements a file of this engine may leave out (0 where it
        does), each row found by its `key` attribute (a body's index, a contact's row)."""
        rows = {int(i): k for k, i in enumerate(self.text(".", key))}
        out = {}
        for field, (element, attrs, dtype, names, presence) in fields.items():
            if presence in ("always", engine):
                continue
            column = np.zeros((self.n, len(attrs)) if len(attrs) > 1 else self.n, dtype)
            for el in self.root.xpath(f"{self.base}[{element}]"):
                found = el.find(element)
                values = [found.get(a) for a in attrs]
                if names is not None:
                    values = [names.index(v) for v in values]
                column[rows[int(el.get(key))]] = values if len(attrs) > 1 else values[0]
            out[field] = column
        return out


def read_step(path, validate=True):
    """Returns (header dict, bodies dict of arrays, contacts dict of arrays)."""
    root = _parse(path, validate)
    h = _child(root, "header", path)
    solver = dict(_child(h, "solver", path).attrib)
    engine = rows_of(solver.get("name"))   # (whose rows the file holds)
    gravity = _child(h, "gravity", path)
    # 2.4.1's step says its iterations; a v3 step its soft step's settings; another engine's, <engine>
    iterations = _child(h, "iterations", path) if engine == "box2d" else None
    soft = _child(h, "soft_step", path) if engine == "box2d3" else None
    own = _child(h, "engine", path) if engine == "own" else None
    header = dict(scene=root.get("scene"), seed=_count(root, "seed", path), index=_count(root, "index", path),
                  time=_float(root, "time", path), dt=_float(root, "dt", path), dt_ratio=_float(root, "dt_ratio", path),
                  gravity=np.array([_float(gravity, "x", path), _float(gravity, "y", path)], np.float32),
                  velocity_iterations=None if iterations is None else _count(iterations, "velocity", path),
                  position_iterations=None if iterations is None else _count(iterations, "position", path),
                  solver=solver, effects=dict(_child(h, "effects", path).attrib),
                  versions=dict(_child(h, "versions", path).attrib),
                  solve=dict(h.find("solve").attrib) if h.find("solve") is not None else None,
                  soft_step=None if soft is None else dict(soft.attrib),
                  engine=None if own is None else dict(own.attrib),
                  engine_step=dict(h.find("engine_step").attrib) if h.find("engine_step") is not None else None)

    bc = _Columns(root, path, "bodies", "body")
    b = bc.read(_BODY, engine=engine)
    b.update(bc.optional(_BODY, "index", engine))   # (elements written only where not zero, or declared)
    b["gravity_scale"] = np.ones(bc.n, np.float32)   # scenes have no per-body gravity scale
    try:
        radius = dict(zip(map(int, root.xpath("bodies/body/shape/*/@fixture")),
                          np.array(root.xpath("bodies/body/shape/*/@radius"), dtype=np.float32)))
    except ValueError:
        raise InputError("a shape's fixture or radius is not a number", path) from None

    cc = _Columns(root, path, "contacts", "contact")
    c = cc.read(_CONTACT, engine=engine)
    c.update(cc.optional(_CONTACT, "index", engine))   # (the other engine's elements: 0)
    try:
        c["radius_a"] = np.array([radius[f] for f in c["fixture_a"].tolist()], np.float32)
        c["radius_b"] = np.array([radius[f] for f in c["fixture_b"].tolist()], np.float32)
    except KeyError as e:
        raise InputError(f"a contact names fixture {e.args[0]}, which no body has", path) from None
    return header, b, c


def read_step_for_grid(path):
    """The fields rasterizing needs, checked, without schema validation."""
    root = _parse(path, validate=False)
    bodies = _Columns(root, path, "bodies", "body").read(_BODY, _BODY_GRID)
    contacts = _Columns(root, path, "contacts", "contact").read(_CONTACT, _CONTACT_GRID)
    header = dict(scene=root.get("scene"), seed=_count(root, "seed", path), index=_count(root, "index", path),
                  solver=dict(_child(_child(root, "header", path), "solver", path).attrib))   # (its engine)
    return header, bodies, contacts
