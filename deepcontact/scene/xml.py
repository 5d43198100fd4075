"""Scene files: read (XSD-validated, then checked) and written (byte-stable)."""

import os
import numpy as np

from .._box2d import format_floats
from ..errors import InputError
from ..xmltext import quoteattr
from .check import check_scene
from .model import Body, Circle, Edge, Effects, Polygon, RemoveEvent, Scene, Solver, f32


def fmt(value) -> str:
    """A float32 as the shortest text that reads back to it."""
    return format_floats(np.array([value], dtype=np.float32))[0]


def _bool(value) -> str:
    return "true" if value else "false"


def _shape_attrs(shape):
    out = []
    if shape.kind == "circle":
        out += [("radius", shape.radius)]
        if shape.x or shape.y:
            out += [("x", shape.x), ("y", shape.y)]
    elif shape.kind == "edge":
        out += [("x1", shape.x1), ("y1", shape.y1), ("x2", shape.x2), ("y2", shape.y2)]
    if shape.kind != "edge" and shape.density:
        out += [("density", shape.density)]
    if shape.friction is not None:
        out += [("friction", shape.friction)]
    if shape.restitution is not None:
        out += [("restitution", shape.restitution)]
    return "".join(f' {k}="{fmt(v)}"' for k, v in out)


def shape_xml(shape, indent="      ") -> str:
    attrs = _shape_attrs(shape)
    if shape.kind != "polygon":
        return f"{indent}<{shape.kind}{attrs}/>\n"
    verts = "".join(f'{indent}  <vertex x="{fmt(x)}" y="{fmt(y)}"/>\n' for x, y in shape.vertices)
    return f"{indent}<polygon{attrs}>\n{verts}{indent}</polygon>\n"


def to_xml(scene: Scene) -> bytes:
    out = ['<?xml version="1.0" encoding="UTF-8"?>\n',
           f'<scene name={quoteattr(scene.name)} format="1">\n']
    if scene.generator:
        seed = "" if scene.seed is None else f' seed="{scene.seed}"'
        out.append(f'  <generator name={quoteattr(scene.generator)}{seed}>\n')
        for k, v in scene.params.items():
            out.append(f'    <param name={quoteattr(k)} value={quoteattr(str(v))}/>\n')
        out.append('  </generator>\n')
    out.append(f'  <world dt="{fmt(scene.dt)}" steps="{scene.steps}"/>\n')
    s = scene.solver
    out.append(f'  <solver velocity_iterations="{s.velocity_iterations}" '
               f'position_iterations="{s.position_iterations}" warm_starting="{_bool(s.warm_starting)}" '
               f'block_solve="{_bool(s.block_solve)}" sleeping="{_bool(s.sleeping)}"/>\n')
    e = scene.effects
    out.append('  <effects>\n')
    if e.gravity is not None:
        out.append(f'    <gravity x="{fmt(e.gravity[0])}" y="{fmt(e.gravity[1])}"/>\n')
    if e.friction is not None:
        out.append(f'    <friction coefficient="{fmt(e.friction)}"/>\n')
    if e.restitution is not None:
        out.append(f'    <restitution coefficient="{fmt(e.restitution)}" '
                   f'threshold="{fmt(e.restitution_threshold)}"/>\n')
    if e.damping is not None:
        out.append(f'    <damping linear="{fmt(e.damping[0])}" angular="{fmt(e.damping[1])}"/>\n')
    if e.continuous:
        out.append('    <continuous/>\n')
    out.append('  </effects>\n  <bodies>\n')
    for b in scene.bodies:
        attrs = f' type="{b.type}"'
        for k in ("x", "y", "angle", "vx", "vy", "omega"):
            v = getattr(b, k)
            if v:
                attrs += f' {k}="{fmt(v)}"'
        if b.fixed_rotation:
            attrs += ' fixed_rotation="true"'
        if b.bullet:
            attrs += ' bullet="true"'
        out.append(f'    <body{attrs}>\n')
        out.extend(shape_xml(sh) for sh in b.shapes)
        out.append('    </body>\n')
    out.append('  </bodies>\n')
    if scene.events:
        out.append('  <events>\n')
        out.extend(f'    <remove step="{ev.step}" body="{ev.body}"/>\n' for ev in scene.events)
        out.append('  </events>\n')
    out.append('</scene>\n')
    return "".join(out).encode("utf-8")


def _num(el, name, default=None):
    v = el.get(name)
    return f32(v) if v is not None else default


def _flag(el, name, default):
    v = el.get(name)
    return default if v is None else v.strip() in ("true", "1")


def _shape(el):
    line = el.sourceline
    common = dict(friction=_num(el, "friction"), restitution=_num(el, "restitution"), line=line)
    if el.tag == "circle":
        return Circle(radius=_num(el, "radius"), x=_num(el, "x", 0.0), y=_num(el, "y", 0.0),
                      density=_num(el, "density", 0.0), **common)
    if el.tag == "polygon":
        verts = tuple((f32(v.get("x")), f32(v.get("y"))) for v in el.findall("vertex"))
        return Polygon(vertices=verts, density=_num(el, "density", 0.0), **common)
    return Edge(x1=_num(el, "x1"), y1=_num(el, "y1"), x2=_num(el, "x2"), y2=_num(el, "y2"), **common)


def read_scene(path: str | os.PathLike) -> Scene:
    """Read, validate against schemas/scene.xsd and check a scene file. Raises InputError."""
    from .. import arguments, schema  # lxml: only needed when reading
    kind, tree, errors = schema.validate(arguments.path(path, "path"), "scene")
    if errors:
        first = errors[0]
        more = f" (and {len(errors) - 1} more errors)" if len(errors) > 1 else ""
        # errors are already "path:line:col: message"
        raise InputError(first.split(": ", 1)[1] + more if ": " in first else first, path,
                         _line_of(first))
    root = tree.getroot()
    world, solver_el, eff = root.find("world"), root.find("solver"), root.find("effects")
    events = []
    if (ev := root.find("events")) is not None:
        events = [RemoveEvent(step=int(r.get("step")), body=int(r.get("body")), line=r.sourceline)
                  for r in ev.findall("remove")]
    gen = root.find("generator")
    scene = Scene(name=root.get("name"), dt=_num(world, "dt"), steps=int(world.get("steps")),
                  solver=_solver(solver_el), effects=_effects(eff),
                  bodies=[_body(b) for b in root.find("bodies").findall("body")], events=events,
                  generator=None if gen is None else gen.get("name"),
                  seed=None if gen is None or gen.get("seed") is None else int(gen.get("seed")),
                  params={} if gen is None else {p.get("name"): p.get("value")
                                                 for p in gen.findall("param")})
    scene.lines = {el.tag: el.sourceline for el in [world, solver_el, *eff] if el is not None and isinstance(el.tag, str)}
    check_scene(scene, path)
    return scene


def _solver(el):
    """A scene file's <solver> (Box2D's defaults where there is none)."""
    if el is None:
        return Solver()
    return Solver(velocity_iterations=int(el.get("velocity_iterations", 8)),
                  position_iterations=int(el.get("position_iterations", 3)),
                  warm_starting=_flag(el, "warm_starting", True), block_solve=_flag(el, "block_solve", True),
                  sleeping=_flag(el, "sleeping", False))


def _effects(eff):
    """A scene file's <effects>: only those it declares are simulated."""
    effects = Effects()
    if (g := eff.find("gravity")) is not None:
        effects.gravity = (_num(g, "x"), _num(g, "y"))
    if (fr := eff.find("friction")) is not None:
        effects.friction = _num(fr, "coefficient", 0.0)
    if (re := eff.find("restitution")) is not None:
        effects.restitution = _num(re, "coefficient", 0.0)
        effects.restitution_threshold = _num(re, "threshold", 1.0)
    if (d := eff.find("damping")) is not None:
        effects.damping = (_num(d, "linear", 0.0), _num(d, "angular", 0.0))
    effects.continuous = eff.find("continuous") is not None
    return effects


def _body(b):
    """A scene file's <body> and its shapes."""
    return Body(type=b.get("type", "dynamic"), x=_num(b, "x", 0.0), y=_num(b, "y", 0.0),
                angle=_num(b, "angle", 0.0), vx=_num(b, "vx", 0.0), vy=_num(b, "vy", 0.0),
                omega=_num(b, "omega", 0.0), fixed_rotation=_flag(b, "fixed_rotation", False),
                bullet=_flag(b, "bullet", False), shapes=[_shape(s) for s in b if isinstance(s.tag, str)],
                line=b.sourceline)


def _line_of(error: str):
    parts = error.split(":")
    try:
        return int(parts[1])
    except (IndexError, ValueError):
        return None
