"""Step files (schemas/step.xsd): the static parts rendered once per simulation here, the
per-step body and contact state rendered natively (deepcontact._box2d.StepWriter)."""

import gzip
import math
import re

from .. import __version__
from .._box2d import StepWriter, polygon_radius
from ..errors import InputError
from ..scene.xml import fmt
from ..xmltext import quoteattr
from .engines import RELAX_ITERATIONS

FORMAT = 1
# gzip level of compressed runs: level 1 makes a pile step about 6x smaller at under a
# millisecond, and it runs in the writer threads beside the stepping (docs/formats.md).
COMPRESS_LEVEL = 1


def _bool(v):
    return "true" if v else "false"


def _shape_xml(scene, fixture, shape, skin):
    friction = fmt(scene.friction_of(shape))
    restitution = fmt(scene.restitution_of(shape))
    tail = f' friction="{friction}" restitution="{restitution}" fixture="{fixture}"'
    if shape.kind == "circle":
        return (f'        <circle radius="{fmt(shape.radius)}" x="{fmt(shape.x)}" y="{fmt(shape.y)}" '
                f'density="{fmt(shape.density)}"{tail}/>\n')
    if shape.kind == "edge":
        return (f'        <edge x1="{fmt(shape.x1)}" y1="{fmt(shape.y1)}" x2="{fmt(shape.x2)}" '
                f'y2="{fmt(shape.y2)}" radius="{fmt(skin)}"{tail}/>\n')
    verts = "".join(f'          <vertex x="{fmt(x)}" y="{fmt(y)}"/>\n' for x, y in shape.vertices)
    return (f'        <polygon density="{fmt(shape.density)}" radius="{fmt(skin)}"{tail}>\n'
            f'{verts}        </polygon>\n')


def body_shapes(scene):
    """The <shape> element of every body, by body index, with fixture indices (polygons and edges
    with Box2D's skin, which a v3 world gives them too)."""
    skin = polygon_radius
    out, fixture = [], 0
    for body in scene.bodies:
        parts = []
        for shape in body.shapes:
            parts.append(_shape_xml(scene, fixture, shape, skin))
            fixture += 1
        out.append("      <shape>\n" + "".join(parts) + "      </shape>\n")
    return out


def header_xml(scene, engine):
    """The <header>'s lines common to every step of `engine` (a simulate.engines.Engine): what
    the engine is and did (<solver>, its own lines: 2.4.1's <iterations>, v3's <soft_step>, another
    engine's <engine>), what the scene asked (<effects>)."""
    e, s = scene.effects, scene.solver
    g = e.gravity if e.gravity is not None else (0.0, 0.0)
    on = set(e.names())
    effects = " ".join(f'{n}="{_bool(n in on)}"'
                       for n in ("gravity", "friction", "restitution", "damping", "continuous"))
    # the Box2D engines' files say their version as they always have; another engine's, in <engine>
    box2d = f' box2d="{engine.version()}"' if engine.rows != "own" else ""
    return ("  <header>\n"
            f'    <gravity x="{fmt(g[0])}" y="{fmt(g[1])}"/>\n'
            f"{engine.header_lines(scene) if engine.rows == 'box2d' else ''}"
            f'    <solver name={quoteattr(engine.solver_name)} warm_starting="{_bool(s.warm_starting)}" '
            f'block_solve="{_bool(s.block_solve and engine.block_solve)}" '
            f'continuous="{_bool(e.continuous and engine.continuous)}" '
            f'sleeping="{_bool(s.sleeping and engine.sleeps)}"/>\n'
            f"{engine.header_lines(scene) if engine.rows != 'box2d' else ''}"
            f"    <effects {effects}/>\n"
            f'    <versions deepcontact="{__version__}"{box2d}/>\n')
    # (the native writer closes <header> after any per-step lines, such as <solve>)


def soft_step_xml(soft, restitution_threshold) -> str:
    """Box2D v3's <soft_step> line: its soft step's settings."""
    return (f'    <soft_step substeps="{soft.substeps}" contact_hertz="{fmt(soft.contact_hertz)}" '
            f'damping_ratio="{fmt(soft.damping_ratio)}" push_speed="{fmt(soft.push_speed)}" '
            f'restitution_threshold="{fmt(restitution_threshold)}" '
            f'relax_iterations="{RELAX_ITERATIONS}"/>\n')


_ATTRIBUTE = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}")
_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def _value(v) -> str:
    if isinstance(v, float) and not math.isfinite(v):
        raise ValueError(f"the value {v!r} is not finite (no NaN or inf in a step file)")
    text = fmt(v) if isinstance(v, float) else str(v).lower() if isinstance(v, bool) else str(v)
    if _CONTROL.search(text):
        raise ValueError(f"the value {text!r} holds a character XML cannot")
    return text


def _attributes(pairs, what) -> str:
    """` key="value"` for each pair, every key a name XML can hold (an engine's settings and
    account of its step are another's code: a key with a space or a control character made every
    step file unreadable); InputError naming `what` otherwise."""
    out = []
    for k, v in pairs:
        if not isinstance(k, str) or not _ATTRIBUTE.fullmatch(k) or k.lower().startswith("xml"):
            raise InputError(f"{what} names {k!r}, which cannot be an XML attribute (letters, digits, _ . -; "
                             f"not starting with a digit or 'xml')")
        try:
            out.append(f" {k}={quoteattr(_value(v))}")
        except ValueError as e:
            raise InputError(f"{what}: {k}: {e}") from None
    return "".join(out)


def engine_xml(name, version, settings) -> str:
    """An engine's <engine> line (an engine without Box2D's own lines): its name, its library's
    version and its settings in effect, one attribute each. InputError naming the engine for text
    XML cannot hold (a plug-in's version() with a control character was the catch-all's ValueError)."""
    extra = _attributes(settings.items(), f"the engine {name!r}'s settings")
    said = {}
    for what, value in (("name", name), ("version", str(version))):
        try:
            said[what] = _value(value)
        except ValueError:
            whose = "the engine's name is" if what == "name" else f"the engine {name!r}: its version() returned"
            raise InputError(f"{whose} {value!r}, which holds a character XML cannot (a control character, a lone "
                             "surrogate, U+FFFE or U+FFFF): no step file could record it") from None
    return f"    <engine name={quoteattr(said['name'])} version={quoteattr(said['version'])}{extra}/>\n"


def engine_step_xml(stats) -> str:
    """A step's <engine_step> line: the engine's own account of its solve (iterations, stop test)."""
    return "    <engine_step" + _attributes(stats.items(), "the engine's account of its step") + "/>\n"


def step_writer(scene, seed, engine) -> StepWriter:
    """The writer of a simulation's steps by `engine` (a simulate.engines.Engine)."""
    root = f' format="{FORMAT}" scene={quoteattr(scene.name)} seed="{seed}" dt="{fmt(scene.dt)}"'
    return StepWriter(root, header_xml(scene, engine), body_shapes(scene), scene.effects.damping is not None,
                      engine.rows)


def step_filename(index: int, compress=False) -> str:
    return f"step-{index:06d}.xml" + (".gz" if compress else "")


def compressed(xml: bytes) -> bytes:
    """A step file as gzip, byte for byte the same for the same step (no time or name inside)."""
    return gzip.compress(xml, COMPRESS_LEVEL, mtime=0)
