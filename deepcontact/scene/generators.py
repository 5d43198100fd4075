"""Built-in scenes: the thesis pile and the hard cases other engines test with: stacks of 15-24
boxes, pyramids of base 20 and 100, mass ratios to 400:1, a card house, an arch held by friction,
625 confined circles, a removed heavy top, a bullet into a stack.

Each generator is a function of a seed and keyword parameters (its defaults give the types);
every one can be written to a scene file with ``dc simulate NAME --write-scene FILE``.
A parameter of 0 for gravity or friction means that effect is off, not simulated with zero.
"""
import inspect
import math

import numpy as np

from .. import arguments
from .._box2d import linear_slop, polygon_radius
from ..errors import InputError, OptionError
from ..resources import SCENE_BYTES_PER_BODY, gigabytes, machine_memory
from .check import check_scene
from .model import Body, Circle, Edge, Effects, Polygon, RemoveEvent, Scene, Solver, f32


# Boxes come to rest in Box2D 2.4.1 with their 1 cm skins overlapping by the linear slop: placing
# them that far apart from the start keeps a stack from being pushed up as it settles. (Box2D v3
# rests skins touching, overlap 0: the generators that place resting contacts take `overlap`.)
def _rest_gap(overlap):
    """The distance between resting polygon surfaces whose skins overlap by `overlap`."""
    return 2 * polygon_radius - overlap


def _effects(gravity, friction, restitution=0.0, continuous=False):
    return Effects(gravity=(0.0, f32(-gravity)) if gravity else None,
                   friction=f32(friction) if friction else None,
                   restitution=f32(restitution) if restitution else None,
                   continuous=continuous)


def _walls(width, height):
    """A static box from (0, 0) to (width, height) made of four two-sided edges."""
    w, h = f32(width), f32(height)
    return Body(type="static", shapes=[Edge(0.0, 0.0, w, 0.0), Edge(w, 0.0, w, h),
                                       Edge(w, h, 0.0, h), Edge(0.0, h, 0.0, 0.0)])


def _ground(half_width=40.0):
    return Body(type="static", shapes=[Edge(f32(-half_width), 0.0, f32(half_width), 0.0)])


def _box(hx, hy, density):
    hx, hy = f32(hx), f32(hy)
    return Polygon(vertices=((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)), density=f32(density))


def _dynamic(x, y, shape, angle=0.0, **kw):
    return Body(type="dynamic", x=f32(x), y=f32(y), angle=f32(angle), shapes=[shape], **kw)


def _squared_distances(a, b):
    """|a_i - b_j|^2 for every pair, as (a - b) ** 2 summed over x and y (the same bits as one
    pair at a time)."""
    dx = a[:, None, 0] - b[None, :, 0]
    dy = a[:, None, 1] - b[None, :, 1]
    return dx * dx + dy * dy


def _clear_of(placed, candidates, min_d2, chunk=1 << 20):
    """Per candidate, whether it is at least sqrt(min_d2) from every placed centre (in chunks of
    about `chunk` distances, so a 10,000-circle pile needs no large matrix)."""
    clear = np.ones(len(candidates), dtype=bool)
    step = max(1, chunk // max(len(placed), 1))
    for i in range(0, len(candidates) if len(placed) else 0, step):
        clear[i:i + step] = _squared_distances(placed, candidates[i:i + step]).min(axis=0) >= min_d2
    return clear


def pile(seed, count=100, box=30.0, radius=1.0, sigma=6.0, density=1.0, friction=0.2,
         gravity=9.81, dt=0.01, steps=600):
    """The thesis world: `count` circles at Gaussian positions (no overlap) falling in a box."""
    rng = np.random.default_rng(seed)
    lo, hi = radius, box - radius
    # Random sequential placement jams near 55% coverage: refuse hopeless requests at once.
    if count * math.pi * radius ** 2 > 0.55 * (box - 2 * radius) ** 2:
        raise InputError(f"pile: {count} circles of radius {radius} cannot be placed without overlap "
                         f"in a {box} box (they would cover over 55% of it)")
    min_d2 = (2.0 * radius + 1e-3) ** 2
    centres = np.empty((count, 2))
    placed = drawn = 0
    while placed < count:
        if drawn > 200 * count + 10000:
            raise InputError(f"pile: could not place {count} circles of radius {radius} without "
                             f"overlap in a {box} box (sigma {sigma}); use fewer or smaller circles")
        batch = rng.normal(box / 2.0, sigma, size=(256, 2))
        drawn += len(batch)
        batch = batch[np.all((batch >= lo) & (batch <= hi), axis=1)]
        # Sequential placement, each candidate kept if clear of every circle placed before it.
        # The distances are computed a batch at a time (to the circles placed before the batch,
        # and within the batch), each the same sum as one at a time, so the same circles.
        blocked = ~_clear_of(centres[:placed], batch, min_d2)
        within = _squared_distances(batch, batch) < min_d2
        for i, p in enumerate(batch):
            if blocked[i]:
                continue
            centres[placed] = p
            placed += 1
            if placed == count:
                break
            blocked |= within[i]
    circles = [_dynamic(x, y, Circle(radius=f32(radius), density=f32(density))) for x, y in centres]
    return dict(effects=_effects(gravity, friction), dt=dt, steps=steps,
                bodies=[_walls(box, box)] + circles)


def stack(seed, count=20, size=1.0, density=1.0, friction=0.6, gravity=9.81, dt=1 / 60, steps=600,
          overlap=linear_slop):
    """A vertical stack of `count` boxes on the ground."""
    gap = _rest_gap(overlap)
    pitch = size + gap
    boxes = [_dynamic(0.0, gap + size / 2 + i * pitch, _box(size / 2, size / 2, density))
             for i in range(count)]
    return dict(effects=_effects(gravity, friction), dt=dt, steps=steps, bodies=[_ground()] + boxes)


def pyramid(seed, base=20, size=1.0, gap=0.05, density=1.0, friction=0.6, gravity=9.81, dt=1 / 60,
            steps=600, overlap=linear_slop):
    """A pyramid of boxes, `base` wide: base (base + 1) / 2 boxes in all."""
    rest = _rest_gap(overlap)
    pitch = size * (1.0 + gap)
    boxes = []
    for row in range(base):
        n = base - row
        for j in range(n):
            boxes.append(_dynamic((j - (n - 1) / 2) * pitch, rest + size / 2 + row * (size + rest),
                                  _box(size / 2, size / 2, density)))
    return dict(effects=_effects(gravity, friction), dt=dt, steps=steps,
                bodies=[_ground(max(40.0, base * pitch))] + boxes)


def mass_ratio(seed, ratio=100.0, radius=0.5, density=1.0, friction=0.6, gravity=9.81, dt=1 / 60,
               steps=600, overlap=polygon_radius):
    """A heavy circle resting on a light one: equal density, areas (and masses) `ratio` : 1. The
    light one starts `overlap` into the ground's skin (default all of it: on the edge itself)."""
    big = radius * math.sqrt(ratio)
    lift = polygon_radius - overlap
    return dict(effects=_effects(gravity, friction), dt=dt, steps=steps, bodies=[
        _ground(),
        _dynamic(0.0, radius + lift, Circle(radius=f32(radius), density=f32(density))),
        _dynamic(0.0, 2 * radius + big + lift, Circle(radius=f32(big), density=f32(density))),
    ])


def card_house(seed, levels=3, length=1.0, thickness=0.004, tilt=15.0, density=1.0, friction=0.7,
               gravity=9.81, dt=1 / 60, steps=600, overlap=linear_slop):
    """A house of cards: `levels` rows of leaning pairs with flat cards across.

    Other engines use 1 mm cards; Box2D 2.4.1 welds polygon vertices closer than 2.5 mm (half
    the linear slop), so 4 mm is the thinnest card here. Box2D's polygon skin (1 cm a side)
    makes every card collide as if it were thicker still."""
    a, t, phi = length / 2, thickness / 2, math.radians(tilt)
    spacing = 4 * a * math.sin(phi) + 0.1 * length   # apex to apex
    card = _box(t, a, density)
    flat = _box(a, t, density)
    bodies = [_ground()]
    gap = _rest_gap(overlap)
    base_y = gap                            # every resting pair of surfaces starts `gap` apart
    for level in range(levels):
        n = levels - level
        apexes = [(j - (n - 1) / 2) * spacing for j in range(n)]
        cy = base_y + a * math.cos(phi) + t * math.sin(phi)
        dx = a * math.sin(phi) + t * math.cos(phi) + gap / (2 * math.cos(phi))
        for xa in apexes:
            bodies.append(_dynamic(xa - dx, cy, card, angle=-phi))   # leaning right
            bodies.append(_dynamic(xa + dx, cy, card, angle=phi))    # leaning left
        top = base_y + 2 * a * math.cos(phi) + 2 * t * math.sin(phi)
        for left, right in zip(apexes, apexes[1:]):
            bodies.append(_dynamic((left + right) / 2, top + gap + t, flat))
        base_y = top + gap + 2 * t + gap
    return dict(effects=_effects(gravity, friction), dt=dt, steps=steps, bodies=bodies)


def arch(seed, blocks=9, inner=4.0, thickness=1.0, density=1.0, friction=0.6, gravity=9.81, dt=1 / 60,
         steps=600, overlap=linear_slop):
    """A semicircular arch of `blocks` voussoirs standing on the ground, held by friction."""
    bodies = [_ground()]
    outer = inner + thickness
    gap = _rest_gap(overlap)

    def face(theta, side):
        # a radial face, moved gap / 2 off the joint so neighbours start at resting distance
        u = np.array([math.cos(theta), math.sin(theta)])
        off = side * (gap / 2) * np.array([-math.sin(theta), math.cos(theta)])
        lift = np.array([0.0, gap / 2])
        return inner * u + off + lift, outer * u + off + lift

    for i in range(blocks):
        t0, t1 = math.pi * i / blocks, math.pi * (i + 1) / blocks
        (i0, o0), (i1, o1) = face(t0, +1), face(t1, -1)
        pts = np.array([i0, o0, o1, i1])
        centre = pts.mean(axis=0)
        local = tuple((f32(x), f32(y)) for x, y in pts - centre)
        bodies.append(_dynamic(centre[0], centre[1], Polygon(vertices=local, density=f32(density))))
    return dict(effects=_effects(gravity, friction), dt=dt, steps=steps, bodies=bodies)


def confined(seed, count=625, radius=0.5, spacing=1.25, speed=1.0, density=1.0, friction=0.0,
             dt=1 / 60, steps=600):
    """`count` circles in a closed box without gravity, started with random velocities."""
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(count))
    pitch = 2 * radius * spacing
    box = side * pitch
    bodies = [_walls(box, box)]
    v = rng.normal(0.0, speed, size=(count, 2))
    for k in range(count):
        i, j = divmod(k, side)
        bodies.append(_dynamic((j + 0.5) * pitch, (i + 0.5) * pitch,
                               Circle(radius=f32(radius), density=f32(density)),
                               vx=f32(v[k, 0]), vy=f32(v[k, 1])))
    return dict(effects=_effects(0.0, friction), dt=dt, steps=steps, bodies=bodies)


def warm_start_energy(seed, radius=0.5, density=1.0, top_density=100.0, remove_step=120, friction=0.6,
                      gravity=9.81, dt=1 / 60, steps=360, overlap=polygon_radius):
    """Three stacked circles; the heavy top one is removed at `remove_step`. The warm start of
    the remaining contacts still carries its weight: that must not launch the others. The lowest
    starts `overlap` into the ground's skin (default all of it: on the edge itself)."""
    lift = polygon_radius - overlap
    bodies = [_ground()] + [
        _dynamic(0.0, radius * (2 * i + 1) + lift, Circle(radius=f32(radius), density=f32(d)))
        for i, d in enumerate((density, density, top_density))]
    return dict(effects=_effects(gravity, friction), dt=dt, steps=steps, bodies=bodies,
                events=[RemoveEvent(step=remove_step, body=3)])


def bullet(seed, stack=10, size=1.0, speed=120.0, radius=0.25, density=1.0, bullet_density=20.0,
           friction=0.6, gravity=9.81, dt=1 / 60, steps=300, overlap=linear_slop):
    """A small fast circle (a Box2D bullet, continuous collision on) fired into a stack of boxes."""
    gap = _rest_gap(overlap)
    boxes = [_dynamic(0.0, gap + size / 2 + i * (size + gap), _box(size / 2, size / 2, density))
             for i in range(stack)]
    shot = _dynamic(-15.0, size * stack / 2, Circle(radius=f32(radius), density=f32(bullet_density)),
                    vx=f32(speed), bullet=True)
    return dict(effects=_effects(gravity, friction, continuous=True), dt=dt, steps=steps,
                bodies=[_ground()] + boxes + [shot])


GENERATORS = {
    "pile": pile,
    "stack": stack,
    "pyramid": pyramid,
    "mass-ratio": mass_ratio,
    "card-house": card_house,
    "arch": arch,
    "confined": confined,
    "warm-start-energy": warm_start_energy,
    "bullet": bullet,
}


def parameters(name):
    """{parameter: default} of a generator."""
    sig = inspect.signature(GENERATORS[name])
    return {k: p.default for k, p in sig.parameters.items() if k != "seed"}


def _convert(name, key, text, default):
    try:
        if isinstance(default, bool):
            if text.lower() in ("true", "1", "yes", "on"):
                return True
            if text.lower() in ("false", "0", "no", "off"):
                return False
            raise ValueError(text)
        value = type(default)(text)
    except ValueError:
        kind = {"int": "whole number", "float": "number", "bool": "true or false"}.get(type(default).__name__,
                                                                                     type(default).__name__)
        raise OptionError(f"generator {name!r}: parameter {key}={text!r} is not a {kind}", "--param") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise OptionError(f"generator {name!r}: parameter {key} must be finite", "--param")
    return value


def _of_its_kind(name, key, value, default):
    """OptionError where a value given as a number is not of its parameter's kind: a whole number
    for a count (5.0 is not), a number for a size, True or False for a switch."""
    if isinstance(default, bool):
        ok = isinstance(value, (bool, np.bool_))
    elif isinstance(default, int):
        ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    else:
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok:
        kind = "true or false" if isinstance(default, bool) else "whole number" if isinstance(default, int) else "number"
        raise OptionError(f"generator {name!r}: parameter {key}={value!r} is not a {kind}", "--param")


# What each parameter may be: sizes, counts and densities positive, the rest not negative.
_POSITIVE = {"count", "box", "radius", "sigma", "size", "density", "top_density", "bullet_density", "ratio",
             "length", "thickness", "inner", "spacing", "dt", "steps", "base", "levels", "blocks", "stack"}
_MAX_PARAM = 1e9   # beyond this a float32 scene overflows anyway; check_scene has the exact limits

# How many bodies a generator makes, known before making them (the memory guard needs it).
BODY_COUNT = {
    "pile": lambda p: p["count"] + 1, "stack": lambda p: p["count"] + 1,
    "pyramid": lambda p: p["base"] * (p["base"] + 1) // 2 + 1, "mass-ratio": lambda p: 3,
    "card-house": lambda p: p["levels"] * (p["levels"] + 1) * 3 // 2 + 1, "arch": lambda p: p["blocks"] + 1,
    "confined": lambda p: p["count"] + 1, "warm-start-energy": lambda p: 4, "bullet": lambda p: p["stack"] + 2,
}


def body_count(name, params=None):
    """An upper estimate of the bodies generate(name, params=params) makes."""
    return int(BODY_COUNT[name](_checked_params(name, params)[0]))


def _checked_params(name, params):
    arguments.text(name, "name")
    if params is not None:
        arguments.mapping(params, "params")
    if name not in GENERATORS:
        raise InputError(f"unknown scene generator {name!r}; choose from {', '.join(GENERATORS)}")
    defaults = parameters(name)
    given = {}
    for key, value in (params or {}).items():
        if key not in defaults:
            raise OptionError(f"generator {name!r} has no parameter {key!r}; "
                             f"its parameters are {', '.join(defaults)}", "--param")
        given[key] = _convert(name, key, value, defaults[key]) if isinstance(value, str) else value
        _of_its_kind(name, key, given[key], defaults[key])
    for key, value in given.items():
        if isinstance(value, bool):
            continue
        if key in _POSITIVE and not value > 0:
            raise OptionError(f"generator {name!r}: {key} must be positive, got {value}", "--param")
        if key not in _POSITIVE and not value >= 0:
            raise OptionError(f"generator {name!r}: {key} must not be negative, got {value}", "--param")
        if not abs(value) <= _MAX_PARAM:
            raise OptionError(f"generator {name!r}: {key}={value:g} is too large (at most {_MAX_PARAM:g})", "--param")
    return {**defaults, **given}, given


def generate(name: str, seed: int = 0, params: dict | None = None, velocity_iterations: int = 8,
             position_iterations: int = 3) -> Scene:
    """Make a scene with a built-in generator. `params` maps names to values of their parameter's
    kind (a whole number for a count, a number for a size, True or False for a switch) or to their
    text, as `--param` gives them. A parameter of another kind, out of its range, or a scene more
    bodies than this machine's memory can make is an OptionError.

    The scene is checked (scene.check.check_scene) before it is returned."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= 2 ** 31 - 1:
        raise OptionError(f"a seed is a whole number from 0 to {2 ** 31 - 1}, got {seed!r}", "--seed")
    every, given = _checked_params(name, params)
    # (the library's own guard, the machine's memory: a command's stricter one, --max-memory, runs first)
    bodies, memory = int(BODY_COUNT[name](every)), machine_memory()
    if memory is not None and bodies * SCENE_BYTES_PER_BODY > memory:
        raise OptionError(f"generator {name!r}: {bodies:,} bodies would need about "
                          f"{gigabytes(bodies * SCENE_BYTES_PER_BODY):.3g} GB of memory to make, more than this "
                          f"machine's {gigabytes(memory):.3g} GB", "--param")
    parts = GENERATORS[name](seed, **given)
    scene = Scene(name=name, dt=f32(parts["dt"]), steps=int(parts["steps"]),
                 solver=Solver(velocity_iterations=velocity_iterations,
                               position_iterations=position_iterations),
                 effects=parts["effects"], bodies=parts["bodies"], events=parts.get("events", []),
                 generator=name, seed=seed, params={k: given[k] for k in sorted(given)})
    check_scene(scene, f"generator {name}")
    return scene
