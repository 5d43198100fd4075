"""What the studies and the closed loop measure of a state or a step, in float64: energy,
penetration, drift from a reference trajectory."""
import numpy as np


def energy(bodies, gravity):
    """Kinetic plus gravitational energy of the dynamic bodies (J), the arrays as the binding gives them."""
    dyn = bodies["type"] == 2
    m = bodies["mass"][dyn].astype(np.float64)
    v = bodies["velocity"][dyn].astype(np.float64)
    w = bodies["omega"][dyn].astype(np.float64)
    inertia = bodies["inertia"][dyn].astype(np.float64)
    c = bodies["center"][dyn].astype(np.float64)
    # (the arrays' own sum: numpy's np.sum without its dispatch, called at every step of a study)
    kinetic = 0.5 * (m * (v * v).sum(axis=1)).sum() + 0.5 * (inertia * w * w).sum()
    potential = -(m * (c @ np.asarray(gravity, dtype=np.float64))).sum()
    return kinetic + potential


def deepest(contacts):
    """The deepest penetration among a step's contact points (m, >= 0; 0 without contacts)."""
    sep = contacts["separation"]
    return max(0.0, float(-sep.min())) if len(sep) else 0.0


def positions(bodies):
    """{body index: position (2,) float64}: what drift compares, body by body (a Positions)."""
    return Positions(bodies["index"], bodies["position"].astype(np.float64))


class Positions(dict):
    """{body index: position (2,) float64}, a plain dict to read, that also holds its bodies as
    two arrays (`index`, `array`: the values are rows of it) until it is changed, so that drift
    compares two of the same bodies in one array operation (a loop compares one a step)."""

    def __init__(self, index, position):
        super().__init__(zip(np.asarray(index).tolist(), position))
        self.index, self.array = np.asarray(index), position

    def _changed(self):
        self.index = self.array = None   # (a value put or taken: the arrays no longer say it)

    def __reduce__(self):
        # (copied or pickled from its arrays, whose rows its values are again; once changed, as a dict)
        if self.array is not None:
            return (Positions, (self.index, self.array))
        return (dict, (list(dict.items(self)),))


def _dropping(name):
    method = getattr(dict, name)

    def call(self, *args, **kwargs):
        self._changed()
        return method(self, *args, **kwargs)
    call.__name__ = call.__qualname__ = name
    call.__doc__ = method.__doc__
    return call


for _name in ("__setitem__", "__delitem__", "update", "pop", "popitem", "clear", "setdefault", "__ior__"):
    setattr(Positions, _name, _dropping(_name))


def drift(a, b):
    """The largest coordinate difference between two `positions` of the bodies present in both
    (removed bodies are not compared; 0 when none is left)."""
    same = _same_bodies(a, b)
    if same is not None:
        return same
    common = a.keys() & b.keys()
    return max((float(np.abs(a[i] - b[i]).max()) for i in common), default=0.0)


def _same_bodies(a, b):
    """drift of two Positions of the same bodies in the same order, in one array operation; None
    where they are not (or the difference is not a number: the body by body max says which)."""
    if getattr(a, "array", None) is None or getattr(b, "array", None) is None or len(a.index) != len(b.index) \
            or not np.array_equal(a.index, b.index):
        return None
    if not len(a.index):
        return 0.0
    d = float(np.abs(a.array - b.array).max())
    return d if d == d else None
