"""Contact keys matched as arrays: which of a step's contact points existed in the step before, and
the step before's impulses by key, without a Python tuple a point.

A key is a row of StepProblem.keys (fixture_a, child_a, fixture_b, child_b, id_key: int64). Rows are
matched whole, natively (key_rows: a hash table of the known rows, a hash only saying where to
compare), so a match is exact.
"""
import numpy as np

from .._box2d import key_rows

_EMPTY_KEYS = np.zeros((0, 5), np.int64)


class KeySet:
    """A step's contact keys, to be looked up by a later step's."""

    def __init__(self, keys=_EMPTY_KEYS):
        """keys: int64 rows of 5."""
        self.keys = np.ascontiguousarray(keys, np.int64).reshape(-1, 5)

    def __len__(self):
        return len(self.keys)

    def find(self, keys):
        """(found, row): for each row of `keys`, whether this set holds it and, where it does, its
        (first) row here."""
        return key_rows(self.keys, np.ascontiguousarray(keys, np.int64).reshape(-1, 5))


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
