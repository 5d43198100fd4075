"""The closed loop's path to its contestants: contact keys matched as arrays (contest/keyed.py)."""
import copy
import pickle

import numpy as np

from deepcontact.contest import keyed
from deepcontact.contest.keyed import KeyedImpulses, KeySet


def _by_tuples(before, now):
    known = set(map(tuple, before.tolist()))
    return np.array([k in known for k in map(tuple, now.tolist())], bool)


def test_keys_are_matched_exactly_as_tuples_are():
    rng = np.random.default_rng(3)
    before, now = rng.integers(0, 4, (400, 5)), rng.integers(0, 4, (300, 5))
    found, row = KeySet(before).find(now)
    assert np.array_equal(found, _by_tuples(before, now)) and 0 < found.sum() < len(now)
    assert np.array_equal(before[row[found]], now[found])


def test_rows_of_one_hash_are_still_told_apart(monkeypatch):
    monkeypatch.setattr(keyed, "hashes", lambda keys: np.zeros(len(keys), np.uint64))   # (every row collides)
    rng = np.random.default_rng(4)
    before, now = rng.integers(0, 3, (50, 5)), rng.integers(0, 3, (40, 5))
    found, row = KeySet(before).find(now)
    assert np.array_equal(found, _by_tuples(before, now)) and found.any() and not found.all()
    assert np.array_equal(before[row[found]], now[found])


def test_previous_impulses_read_as_the_dict_a_start_was_given():
    keys = np.array([[1, 0, 2, 0, 7], [3, 0, 4, 0, 9]], np.int64)
    plain = {(1, 0, 2, 0, 7): (0.5, -0.25), (3, 0, 4, 0, 9): (1.5, 0.0)}
    previous = KeyedImpulses(keys, [0.5, 1.5], [-0.25, 0.0])
    assert isinstance(previous, dict) and previous == plain and dict(previous) == plain and {**previous} == plain
    assert previous.get((3, 0, 4, 0, 9)) == (1.5, 0.0) and (9, 9, 9, 9, 9) not in previous and len(previous) == 2
    again = pickle.loads(pickle.dumps(KeyedImpulses(keys, [0.5, 1.5], [-0.25, 0.0])))
    assert again == plain and copy.deepcopy(again) == plain and not KeyedImpulses()
    previous[(0, 0, 0, 0, 0)] = (1.0, 1.0)   # (a start's own copy, changed as a dict is)
    assert pickle.loads(pickle.dumps(previous)) == {**plain, (0, 0, 0, 0, 0): (1.0, 1.0)}
