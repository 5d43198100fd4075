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
    """{body index: position (2,) float64}: what drift compares, body by body."""
    return dict(zip(bodies["index"].tolist(), bodies["position"].astype(np.float64)))


def drift(a, b):
    """The largest coordinate difference between two `positions` of the bodies present in both
    (removed bodies are not compared; 0 when none is left)."""
    common = a.keys() & b.keys()
    return max((float(np.abs(a[i] - b[i]).max()) for i in common), default=0.0)
