"""Reading step files back into the same arrays the binding produces.

The slow, obvious reader (lxml + Python): used by tests as the reference for the native
writer's output, and by tools that read a step at a time."""
import numpy as np

from .. import schema
from ..errors import InputError

_MANIFOLD = {"circles": 0, "face_a": 1, "face_b": 2}
_TYPE = {"static": 0, "kinematic": 1, "dynamic": 2}


def _f(el, name):
    return np.float32(el.get(name))


def read_step(path, validate=True):
    """Returns (header dict, bodies dict of arrays, contacts dict of arrays)."""
    if validate:
        _, tree, errors = schema.validate(path, "step")
        if errors:
            first = errors[0].split(":", 3)
            raise InputError(first[3].strip(), path, int(first[1]) if first[1].isdigit() else None)
    else:
        tree = schema.parse(path)
    root = tree.getroot()
    h = root.find("header")
    header = dict(scene=root.get("scene"), seed=int(root.get("seed")), index=int(root.get("index")),
                  time=np.float32(root.get("time")), dt=np.float32(root.get("dt")),
                  dt_ratio=np.float32(root.get("dt_ratio")),
                  gravity=np.array([_f(h.find("gravity"), "x"), _f(h.find("gravity"), "y")], np.float32),
                  velocity_iterations=int(h.find("iterations").get("velocity")),
                  position_iterations=int(h.find("iterations").get("position")),
                  solver=dict(h.find("solver").attrib), effects=dict(h.find("effects").attrib),
                  versions=dict(h.find("versions").attrib))

    rows = root.find("bodies").findall("body")
    n = len(rows)
    b = {k: np.zeros(n, np.float32) for k in ("angle", "omega", "mass", "inv_mass", "inertia",
                                              "inv_inertia", "linear_damping", "angular_damping")}
    b.update({k: np.zeros((n, 2), np.float32) for k in ("position", "center", "local_center", "velocity")})
    b["gravity_scale"] = np.ones(n, np.float32)   # scenes have no per-body gravity scale
    radius = {}                                     # fixture index -> collision radius
    b["index"] = np.zeros(n, np.int32)
    b["type"] = np.zeros(n, np.int8)
    for i, el in enumerate(rows):
        b["index"][i] = int(el.get("index"))
        b["type"][i] = _TYPE[el.get("type")]
        for key in ("position", "center", "velocity"):
            e = el.find(key)
            b[key][i] = (_f(e, "x"), _f(e, "y"))
        if (lc := el.find("local_center")) is not None:
            b["local_center"][i] = (_f(lc, "x"), _f(lc, "y"))
        for shape in el.find("shape"):
            if isinstance(shape.tag, str):
                radius[int(shape.get("fixture"))] = _f(shape, "radius")
        b["angle"][i] = _f(el.find("orientation"), "theta")
        b["omega"][i] = _f(el.find("spin"), "omega")
        b["mass"][i], b["inv_mass"][i] = _f(el.find("mass"), "value"), _f(el.find("mass"), "inverse")
        b["inertia"][i] = _f(el.find("inertia"), "value")
        b["inv_inertia"][i] = _f(el.find("inertia"), "inverse")
        if (d := el.find("damping")) is not None:
            b["linear_damping"][i], b["angular_damping"][i] = _f(d, "linear"), _f(d, "angular")

    rows = root.find("contacts").findall("contact")
    m = len(rows)
    c = {k: np.zeros(m, np.int32) for k in ("manifold", "island", "body_a", "body_b", "fixture_a",
                                            "fixture_b", "child_a", "child_b")}
    c.update({k: np.zeros(m, np.int8) for k in ("point", "point_count", "manifold_type")})
    c["id_key"] = np.zeros(m, np.uint32)
    c.update({k: np.zeros((m, 2), np.float32) for k in ("local_normal", "local_point", "point_local",
                                                        "position", "normal")})
    c.update({k: np.zeros(m, np.float32) for k in (
        "separation", "friction", "restitution", "restitution_threshold", "start_normal_impulse",
        "start_tangent_impulse", "normal_impulse", "tangent_impulse")})
    for i, el in enumerate(rows):
        c["manifold"][i], c["island"][i] = int(el.get("manifold")), int(el.get("island"))
        c["point"][i], c["point_count"][i] = int(el.get("point")), int(el.get("points"))
        c["body_a"][i], c["body_b"][i] = int(el.get("master")), int(el.get("slave"))
        c["id_key"][i] = int(el.get("id"))
        fx = el.find("fixtures")
        c["fixture_a"][i], c["child_a"][i] = int(fx.get("master")), int(fx.get("master_child"))
        c["fixture_b"][i], c["child_b"][i] = int(fx.get("slave")), int(fx.get("slave_child"))
        for key in ("position", "normal"):
            e = el.find(key)
            c[key][i] = (_f(e, "x"), _f(e, "y"))
        c["separation"][i] = _f(el.find("separation"), "value")
        mat = el.find("material")
        c["friction"][i], c["restitution"][i] = _f(mat, "friction"), _f(mat, "restitution")
        c["restitution_threshold"][i] = _f(mat, "threshold")
        c["normal_impulse"][i], c["tangent_impulse"][i] = _f(el.find("impulse"), "n"), _f(el.find("impulse"), "t")
        st = el.find("start")
        c["start_normal_impulse"][i], c["start_tangent_impulse"][i] = _f(st, "n"), _f(st, "t")
        mf = el.find("manifold")
        c["manifold_type"][i] = _MANIFOLD[mf.get("type")]
        c["local_normal"][i] = (_f(mf, "nx"), _f(mf, "ny"))
        c["local_point"][i] = (_f(mf, "x"), _f(mf, "y"))
        c["point_local"][i] = (_f(mf, "px"), _f(mf, "py"))
    c["radius_a"] = np.array([radius[f] for f in c["fixture_a"]], np.float32)
    c["radius_b"] = np.array([radius[f] for f in c["fixture_b"]], np.float32)
    return header, b, c


_GRID_BODY = {"center": ("center", ("x", "y")), "velocity": ("velocity", ("x", "y")),
              "mass": ("mass", ("value",)), "omega": ("spin", ("omega",))}
_GRID_CONTACT = {"position": ("position", ("x", "y")), "normal": ("normal", ("x", "y")),
                 "impulse": ("impulse", ("n", "t"))}


def read_step_for_grid(path):
    """The fields rasterizing needs, fast (one XPath per column) and checked: a truncated or
    malformed file, a missing value or a NaN is an InputError naming the file (and line)."""
    from lxml import etree
    try:
        root = schema.parse(path).getroot()
    except etree.XMLSyntaxError as e:
        raise InputError(f"not a well-formed step file: {e.msg}", path, e.lineno) from None
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror or e}", path) from None
    if root.tag != "step":
        raise InputError(f"root element is <{root.tag}>, not <step>", path, root.sourceline)

    def columns(parent, child, spec):
        n = len(root.xpath(f"{parent}/{child}"))
        out = {}
        for key, (element, attrs) in spec.items():
            cols = []
            for a in attrs:
                text = root.xpath(f"{parent}/{child}/{element}/@{a}")
                if len(text) != n:
                    raise InputError(f"{n - len(text)} <{child}> element(s) lack <{element} {a}=...>", path)
                try:
                    cols.append(np.array(text, dtype=np.float32))
                except ValueError:
                    raise InputError(f"a <{element} {a}> value is not a number", path) from None
            arr = np.stack(cols, axis=1) if len(cols) > 1 else cols[0]
            if not np.all(np.isfinite(arr)):
                bad = int(np.argmax(~np.isfinite(arr).reshape(n, -1).all(axis=1)))
                line = root.xpath(f"{parent}/{child}")[bad].sourceline
                raise InputError(f"<{element}> of {child} {bad} is not finite", path, line)
            out[key] = arr
        return out, n

    bodies, nb = columns("bodies", "body", _GRID_BODY)
    bodies["type"] = np.array([_TYPE.get(t, -1) for t in root.xpath("bodies/body/@type")], dtype=np.int8)
    if np.any(bodies["type"] < 0):
        raise InputError("a body has an unknown type", path)
    contacts, nc = columns("contacts", "contact", _GRID_CONTACT)
    imp = contacts.pop("impulse").reshape(nc, 2)
    contacts["normal_impulse"], contacts["tangent_impulse"] = imp[:, 0], imp[:, 1]
    for key in ("center", "velocity"):
        bodies[key] = bodies[key].reshape(nb, 2)
    for key in ("position", "normal"):
        contacts[key] = contacts[key].reshape(nc, 2)
    header = dict(scene=root.get("scene"), seed=int(root.get("seed", 0)), index=int(root.get("index", 0)))
    return header, bodies, contacts
