"""drift between two trails' positions: two of the same bodies compared in one array operation
(solver/metrics.py Positions), the same number the body by body comparison gives."""
import copy
import pickle

import numpy as np
import pytest

from deepcontact.solver.metrics import Positions, drift, positions


def by_body(a, b):
    """drift as it compares: body by body, over the bodies both hold."""
    return max((float(np.abs(a[i] - b[i]).max()) for i in a.keys() & b.keys()), default=0.0)


def bodies(index, rng):
    return {"index": np.asarray(index, np.int32), "position": rng.normal(0, 5, (len(index), 2)).astype(np.float32)}


@pytest.mark.parametrize("seed", range(5))
def test_drift_of_the_same_bodies_is_the_body_by_body_drift(seed):
    rng = np.random.default_rng(seed)
    a, b = positions(bodies(range(50), rng)), positions(bodies(range(50), rng))
    assert isinstance(a, dict) and a.keys() == set(range(50)) and np.array_equal(a[7], a.array[7])
    assert drift(a, b) == by_body(a, b) > 0 and drift(a, a) == 0.0
    # (the kept reference's trail: int64 indexes, float64 rows of one array)
    kept = Positions(np.arange(50, dtype=np.int64), b.array.copy())
    assert drift(a, kept) == by_body(a, b)


def test_other_bodies_a_change_or_a_nan_are_compared_body_by_body():
    rng = np.random.default_rng(9)
    a = positions(bodies(range(40), rng))
    fewer = positions(bodies([*range(10), *range(11, 40)], rng))   # (a body removed)
    assert drift(a, fewer) == by_body(a, fewer)
    changed = positions(bodies(range(40), rng))
    far = np.array([1e3, -1e3])
    changed[3] = far   # (the arrays no longer hold what the dict does)
    assert changed.array is None and drift(a, changed) == by_body(a, changed) == pytest.approx(1e3, rel=0.1)
    nan = positions(bodies(range(40), rng))
    nan[5][0] = np.nan   # (a value changed in place: a row of its array)
    assert np.isnan(nan.array[5, 0]) and drift(a, nan) == by_body(a, nan)
    assert drift(a, dict(a)) == 0.0 and drift(Positions([], np.zeros((0, 2))), Positions([], np.zeros((0, 2)))) == 0.0


def test_positions_copied_or_pickled_keep_their_rows():
    rng = np.random.default_rng(2)
    a = positions(bodies(range(20), rng))
    for again in (copy.deepcopy(a), pickle.loads(pickle.dumps(a))):
        assert again.keys() == a.keys() and drift(again, a) == 0.0
        again[4][1] += 1.0   # (its values are rows of its own array, not of a's)
        assert drift(again, a) == 1.0 == by_body(again, a) and a[4][1] != again[4][1]
    a.pop(3)
    plain = pickle.loads(pickle.dumps(a))
    assert plain.keys() == a.keys() and drift(plain, a) == 0.0
