"""Contact keys matched as arrays: which of a step's contact points existed in the step before, and
the step before's impulses by key, without a Python tuple a point.

A key is a row of StepProblem.keys (fixture_a, child_a, fixture_b, child_b, id_key: int64). Rows are
matched by a 64-bit hash of the row, then compared whole, so a match is exact; where two different
rows share a hash (never seen; possible in principle) the step is matched row by row as tuples.
"""
import numpy as np

# (odd multipliers, one a column: a row's hash is their sum of products, modulo 2**64)
_MULTIPLIERS = np.array([0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0xD6E8FEB86659FD93,
                         0xFF51AFD7ED558CCD], np.uint64)
_EMPTY_KEYS = np.zeros((0, 5), np.int64)


def hashes(keys):
    """One uint64 per key row (equal rows, equal hashes); keys: int64 rows of 5, contiguous."""
    return keys.view(np.uint64) @ _MULTIPLIERS


class KeySet:
    """A step's contact keys, sorted by hash once, to be looked up by a later step's."""

    def __init__(self, keys=_EMPTY_KEYS, h=None):
        """keys: int64 rows of 5; h: their hashes, where the caller has them."""
        self.keys = np.ascontiguousarray(keys, np.int64).reshape(-1, 5)
        h = hashes(self.keys) if h is None else h
        self.order = np.argsort(h, kind="stable")
        self.sorted = h[self.order]

    def __len__(self):
        return len(self.keys)

    def find(self, keys, h=None):
        """(found, row): for each row of `keys` (h: their hashes, where the caller has them),
        whether this set holds it and, where it does, its row here."""
        keys = np.ascontiguousarray(keys, np.int64).reshape(-1, 5)
        if not len(self.keys) or not len(keys):
            return np.zeros(len(keys), bool), np.zeros(len(keys), np.intp)
        h = hashes(keys) if h is None else h
        at = np.minimum(np.searchsorted(self.sorted, h), len(self.sorted) - 1)
        row = self.order[at]
        found = self.sorted[at] == h
        if not np.array_equal(self.keys[row[found]], keys[found]):   # (two rows of one hash: matched as tuples)
            return self._by_tuples(keys)
        return found, row

    def _by_tuples(self, keys):
        where = {k: i for i, k in enumerate(map(tuple, self.keys.tolist()))}
        rows = [where.get(k, -1) for k in map(tuple, keys.tolist())]
        row = np.array(rows, np.intp).reshape(-1)
        return row >= 0, np.maximum(row, 0)


class KeyedImpulses(dict):
    """{contact key: (normal, tangent)} of a step's solution, as StepContext.previous holds it, kept
    as its arrays until a start reads it (the `prev` start does; builtin never): a dict in every
    way a start uses one, filled on its first read, and pickled as its three arrays while unread."""

    def __init__(self, keys=_EMPTY_KEYS, normal=(), tangent=()):
        super().__init__()
        self._arrays = (np.asarray(keys, np.int64).reshape(-1, 5), np.asarray(normal, np.float64),
                        np.asarray(tangent, np.float64))

    def _fill(self):
        if self._arrays is not None:
            keys, normal, tangent = self._arrays
            self._arrays = None
            dict.update(self, zip(map(tuple, keys.tolist()), zip(normal.tolist(), tangent.tolist())))
        return self

    def __reduce__(self):
        if self._arrays is not None:
            return (KeyedImpulses, self._arrays)
        return (dict, (list(dict.items(self)),))


def _filled(name):
    method = getattr(dict, name)

    def call(self, *args, **kwargs):
        return method(self._fill(), *args, **kwargs)
    call.__name__ = call.__qualname__ = name
    call.__doc__ = method.__doc__
    return call


for _name in ("__getitem__", "get", "__contains__", "__iter__", "__len__", "keys", "values", "items", "__repr__",
              "__eq__", "__ne__", "copy", "__setitem__", "__delitem__", "pop", "popitem", "setdefault", "update",
              "clear", "__or__", "__ior__", "__reversed__"):
    setattr(KeyedImpulses, _name, _filled(_name))
KeyedImpulses.__hash__ = None
