"""The closed loop's steps in shared memory: a step's context written once by the judge, read by
the variant's contestant and the null contestant, with no pickling on the path.

Each variant has a channel (StepChannel): an arena (a memfd the judge maps for writing) holding the
step's columns, and, for an oracle only, a second arena holding the columns only an oracle may see
(the step's reference solution, the recorded impulses: OracleSlots). A contestant is handed
read-only descriptors of them (SCM_RIGHTS over its socket, once, or again when an arena is made
larger), maps them read-only, and copies a step out of them before building its ctx from the
copy: what it keeps across steps is its own, and it can change nothing the judge or the null reads.

An arena begins with a header: the step's sequence number, its index, the row count of each column;
then the columns, each at a multiple of 64 bytes (written and read back natively: arena_put,
arena_views). What the columns are (their dtype, their shape but
the rows, and which table of the ctx holds each) is the channel's schema, sent pickled once and
again only when it changes (it does not while a loop runs). A step's request on the socket is then
16 bytes: its sequence number and the channel; a contestant refuses a request whose sequence
number is not the arena's or not newer than the last it read.

Once a channel's schema is made (from a ctx, as a start may see it), an ordinary start's later steps
can be written straight from the world (write_world: arena_put_world), each column taken where
World.bodies() and World.contacts() take it or made of them as the judge's ctx makes it, the same
bytes without a numpy array or a dict a column. An oracle's channel never is (nor is a schema with
an entry only an oracle may see, and the world gives no such column: world_columns), and where a
step cannot be (see write_world) its ctx is written.
"""
import dataclasses
import mmap
import operator
import os
import pickle
import struct

import numpy as np

from .._box2d import arena_put, arena_put_world, arena_tables, arena_views, world_columns

STEP = b"S"           # a step's request begins so (a pickled request begins b"\x80")
FDS = b"F"            # the byte the descriptors come with
HEAD = struct.Struct("<qqqIIQ")   # sequence number, ctx's index, its problem's, columns, schema version, bytes used
REQUEST = struct.Struct("<cxxxIQ")   # STEP, the channel, the sequence number
ALIGN = 64
LEAST = 1 << 20       # bytes an arena starts with (a 100-circle step takes about 40 KiB)
F_SEAL_FUTURE_WRITE = 0x10   # (linux/fcntl.h; Python's fcntl does not name it)
ORACLE_SLOTS = {("contacts", "normal_impulse"), ("contacts", "tangent_impulse"), ("problem", "normal_impulse"),
                ("problem", "tangent_impulse")}   # (and every ("reference", ...)): what only an oracle may see
PROBLEM_ARRAYS = ("start_normal", "start_tangent", "normal_impulse", "tangent_impulse", "keys")
PROBLEM_SCALARS = ("dt", "gravity", "block_solve", "velocity_iterations")
CONTEXT_SCALARS = ("seed", "variant", "trajectory")


class StaleStep(ValueError):
    """A step's request whose sequence number is not its arena's, or not newer than the last read."""


def _aligned(n):
    return (n + ALIGN - 1) // ALIGN * ALIGN


class Arena:
    """One memfd of the judge's, mapped for writing; made again, larger, when a step does not fit
    (its generation then counts up, and every reader is handed the new one)."""

    def __init__(self, name, size=0):
        self.name, self.generation, self.fd, self.map = name, 0, None, None
        self._make(size)

    def _make(self, size):
        self.close()
        self.size = _aligned(max(size, LEAST))
        self.fd = os.memfd_create(self.name, os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
        os.ftruncate(self.fd, self.size)
        self.map = mmap.mmap(self.fd, self.size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        self.view = memoryview(self.map)
        self.generation += 1
        self.sealed = _seal(self.fd)

    def reader(self):
        """A new read-only descriptor of it (the receiver's to close): neither it nor a mapping of
        it can write, grow or seal the arena."""
        return os.open(f"/proc/self/fd/{self.fd}", os.O_RDONLY | os.O_CLOEXEC)

    def put(self, seq, index, count, version, write):
        """Writes a step: its `count` columns by write(buffer, head) (natively, in one call:
        arena_put or arena_put_world, each at a multiple of ALIGN after a header of `head` bytes),
        which returns (bytes used, ...): minus the bytes needed where the arena is too small (made
        larger, and written again), 0 where nothing is a step; then its header (index: the ctx's
        and its problem's), the sequence number last, where the bytes used are more than 0. What
        write returned."""
        done = write(self.map, HEAD.size)
        if done[0] < 0:
            self._make(-2 * done[0])
            done = write(self.map, HEAD.size)
        if done[0] > 0:
            HEAD.pack_into(self.map, 0, seq, *index, count, version, done[0])
        return done

    def close(self):
        """Unmaps it and closes its descriptor (a reader's mapping stays valid)."""
        if self.map is not None:
            self.view.release()
            self.map.close()
            os.close(self.fd)
            self.map = None


def _seal(fd):
    """Seals a memfd mapped for writing against every later write but through that mapping, and
    against any change of size: a read-only descriptor can be opened again for writing (through
    /proc/self/fd, by its inode's mode), and the seal is what refuses that descriptor a write or a
    shared writable mapping. False on a kernel without F_SEAL_FUTURE_WRITE (before 5.1), where
    the descriptors' being read-only and closed before any plug-in code runs is the fence."""
    import fcntl
    try:
        fcntl.fcntl(fd, fcntl.F_ADD_SEALS, F_SEAL_FUTURE_WRITE | fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW
                    | fcntl.F_SEAL_SEAL)
    except OSError:
        return False
    return True


@dataclasses.dataclass
class Schema:
    """What a channel's arenas hold: for each table entry of the ctx (slot, name) the arena and
    column holding it; each arena's columns (dtype, trailing shape); the ctx's scalars."""
    entries: tuple
    columns: dict
    scalars: tuple


def _tables(ctx):
    """(names, arrays, scalars) of a ctx: its tables' names, ((slot, (name, ...)), ...), in a
    fixed order; their arrays, in that order; ((name, value), ...) of its scalars."""
    p = ctx.problem
    tables = [("bodies", ctx.bodies), ("contacts", ctx.contacts), ("problem.bodies", p.bodies),
              ("problem.contacts", p.contacts),
              ("problem", {k: getattr(p, k) for k in PROBLEM_ARRAYS if getattr(p, k) is not None}),
              ("ctx", {"persisted": ctx.persisted}),
              ("previous", dict(zip(("keys", "normal", "tangent"), _previous_arrays(ctx.previous))))]
    if ctx.reference is not None:
        r = ctx.reference
        arrays = {f.name: getattr(r, f.name) for f in dataclasses.fields(r)
                  if isinstance(getattr(r, f.name), np.ndarray)}
        rest = {f.name: getattr(r, f.name) for f in dataclasses.fields(r) if f.name not in arrays}
        arrays[""] = np.frombuffer(pickle.dumps(rest, protocol=pickle.HIGHEST_PROTOCOL), np.uint8)
        tables.append(("reference", arrays))
    scalars = (tuple((k, getattr(p, k)) for k in PROBLEM_SCALARS), tuple((k, getattr(ctx, k)) for k in CONTEXT_SCALARS))
    return tuple((slot, tuple(t)) for slot, t in tables), [a for _, t in tables for a in t.values()], scalars


def _items(names, arrays):
    """[(slot, name, array)] of _tables' names and arrays."""
    return [(slot, name, a) for (slot, name), a in zip(((s, n) for s, ns in names for n in ns), arrays)]


def _previous_arrays(previous):
    """(keys, normal, tangent) arrays of the previous step's impulses by key (keyed.KeyedImpulses
    holds them so until read; any other mapping is read here)."""
    held = getattr(previous, "_arrays", None)
    if held is not None:
        return held
    items = list((previous or {}).items())
    keys = np.array([k for k, _ in items], np.int64).reshape(-1, 5)
    values = np.array([v for _, v in items], np.float64).reshape(-1, 2)
    return keys, np.ascontiguousarray(values[:, 0]), np.ascontiguousarray(values[:, 1])


def _is_oracle(slot, name):
    return slot == "reference" or (slot, name) in ORACLE_SLOTS


def _columns(items, oracle):
    """(entries, columns, arrays) of a ctx's arrays (_tables): each array once, in the plain arena
    unless only an oracle's entries hold it; ValueError where an oracle's entry is among the
    items of a channel that is not an oracle's."""
    plain = {id(a) for slot, name, a in items if not _is_oracle(slot, name)}
    if not oracle and len(plain) < len({id(a) for _, _, a in items}):
        raise ValueError("an ordinary start's ctx holds what only an oracle may see")
    entries, where = [], {}
    columns, arrays = {"plain": [], "oracle": []}, {"plain": [], "oracle": []}
    for slot, name, a in items:
        at = where.get(id(a))
        if at is None:
            kind = "plain" if id(a) in plain else "oracle"
            at = where[id(a)] = (kind, len(arrays[kind]))
            columns[kind].append((a.dtype.str, a.shape[1:]))
            arrays[kind].append(a)
        entries.append((slot, name, *at))
    return tuple(entries), {k: tuple(v) for k, v in columns.items()}, arrays


def _forms_of(arrays):
    """arena_put's forms of `arrays`: an int64 row each (its dtype's number, byte order, item
    size, its count of trailing dimensions and each of them, padded with -1)."""
    rows = [(a.dtype.num, ord(a.dtype.byteorder), a.dtype.itemsize, a.ndim - 1, *a.shape[1:]) for a in arrays]
    out = np.full((len(rows), max([4, *map(len, rows)])), -1, np.int64)
    for i, row in enumerate(rows):
        out[i, :len(row)] = row
    return out


def _world_codes(schema):
    """The world_columns code of each of the schema's columns, an int64 array, or None where one
    is not a column the world gives in its form (each column named by its first entry), or where
    an entry is one only an oracle may see (which no column the world gives is)."""
    given = {(slot, name): (code, dtype.str, () if width == 1 else (width,))
             for slot, name, code, dtype, width in world_columns()}
    first = {}
    for slot, name, kind, column in schema.entries:
        if kind != "plain" or _is_oracle(slot, name):
            return None
        first.setdefault(column, (slot, name))
    codes = []
    for column, form in enumerate(schema.columns["plain"]):
        code, dtype, shape = given.get(first.get(column), (None, None, None))
        if code is None or (dtype, shape) != (form[0], tuple(form[1])):
            return None
        codes.append(code)
    return np.array(codes, np.int64)


def _getter(positions):
    """A function of a sequence: the tuple of its entries at `positions` (operator.itemgetter,
    which gives a bare entry for one position and fails on none)."""
    if len(positions) > 1:
        return operator.itemgetter(*positions)
    return lambda seq: tuple(seq[k] for k in positions)


class StepChannel:
    """One variant's steps in shared memory, written by the judge (write), each request sent to
    its contestant and the null contestant alike (client.Contestant.call_step)."""

    _count = 0

    def __init__(self, oracle):
        StepChannel._count += 1
        self.ident, self.oracle = StepChannel._count, oracle
        self.arenas = {"plain": Arena("dc-arena")}
        if oracle:
            self.arenas["oracle"] = Arena("dc-oracle-arena")
        self.seq, self.version, self.schema, self.schema_bytes = 0, 0, None, b""
        self.world_codes = None   # (write_world's columns, by their world_columns codes)
        self.told = {}   # receiver -> (the generations of the arenas it holds, the schema version it holds)

    def write(self, ctx):
        """Writes a step's ctx (as its start may see it: replay.visible_context); its request's bytes."""
        names, arrays, scalars = _tables(ctx)
        held = self._as_before(names, arrays, scalars)
        self.seq += 1
        if held is None or not self._put(ctx, held):
            # (the first step, or one whose tables changed: a schema of its own)
            items = _items(names, arrays)
            entries, columns, held = _columns(items, self.oracle)
            self._new_schema(Schema(entries, columns, scalars), names, arrays, held)
            if not self._put(ctx, held):
                raise ValueError("a step's column is not of the form its own schema gives it")
        return REQUEST.pack(STEP, self.ident, self.seq)

    def write_world(self, world, carried, known, previous, index):
        """Writes the step `world` holds (posed: pgs_pose) as `write` writes its ctx, straight from
        the world: (its request's bytes, its contact keys), or None where it cannot be (no schema
        yet, an oracle's channel, a column the world does not give, a body not finite, a contact
        naming a body the world does not hold: the caller writes the ctx, which says what is
        wrong). carried: Box2D's warm-start scale (np.float32); known: the step before's keys
        (int64 rows of 5); previous: its solution by key (ctx.previous: keyed.KeyedImpulses);
        index: (ctx.index, ctx.problem.index) of the step."""
        if self.world_codes is None:
            return None
        previous = _previous_arrays(previous)

        def write(buffer, head):   # (bodies not finite: no step, and the ctx says so)
            used, keys, finite = arena_put_world(world, buffer, head, self.world_codes, carried, known, *previous)
            return (used if finite or used < 0 else 0), keys
        used, keys = self.arenas["plain"].put(self.seq + 1, index, len(self.world_codes), self.version, write)
        if used <= 0:
            return None
        self.seq += 1
        return REQUEST.pack(STEP, self.ident, self.seq), keys

    def _put(self, ctx, arrays):
        index = (int(ctx.index), int(ctx.problem.index))
        written = []
        for kind, arena in self.arenas.items():
            def write(buffer, head, columns=arrays[kind], forms=self.forms[kind]):
                return (arena_put(buffer, head, columns, forms),)
            written.append(arena.put(self.seq, index, len(arrays[kind]), self.version, write)[0] > 0)
        return all(written)

    def _as_before(self, names, arrays, scalars):
        """The arrays to write, by arena, where the step's tables are laid out as the last
        schema's (the same names, the same arrays shared among them), else None; each column's
        dtype and trailing shape are held to the schema's as it is written (Arena.put)."""
        if self.schema is None or names != self.names or scalars != self.schema.scalars:
            return None
        ids = tuple(map(id, arrays))
        # (the same arrays shared: each entry's array that of the first entry sharing it before,
        # and as many arrays as before)
        if self.firsts(ids) != ids or len(set(ids)) != self.distinct:
            return None
        return {kind: list(take(arrays)) for kind, take in self.takes.items()}

    def _new_schema(self, schema, names, arrays, held):
        self.schema, self.version = schema, self.version + 1
        first = {}
        pattern = [first.setdefault(id(a), k) for k, a in enumerate(arrays)]
        self.firsts = _getter(pattern)
        self.distinct = len(first)
        self.names = names
        self.takes = {kind: _getter([first[id(a)] for a in v]) for kind, v in held.items()}
        self.forms = {kind: _forms_of(v) for kind, v in held.items()}
        self.world_codes = None if self.oracle else _world_codes(schema)
        self.schema_bytes = pickle.dumps({"op": "arena", "channel": self.ident, "version": self.version,
                                          "schema": dataclasses.asdict(schema)}, protocol=pickle.HIGHEST_PROTOCOL)

    def setup_for(self, receiver):
        """(the schema's bytes or None, the read-only descriptors to hand `receiver`, or none):
        what it lacks of this channel before it reads the step."""
        generations = tuple(a.generation for a in self.arenas.values())
        held = self.told.get(receiver)
        if held == (generations, self.version):
            return None, []
        self.told[receiver] = (generations, self.version)
        fds = [] if held is not None and held[0] == generations else [a.reader() for a in self.arenas.values()]
        return self.schema_bytes, fds

    def close(self):
        """Closes its arenas."""
        for arena in self.arenas.values():
            arena.close()


# --- The contestant's side ------------------------------------------------------------------------

class Mapped:
    """The channels a contestant was handed, mapped read-only; each step copied out and made a ctx."""

    def __init__(self):
        self.channels = {}   # channel -> {"schema", "version", "maps": {kind: mmap}, "seq"}
        self.socket = None   # (the contestant's line as a socket, to receive descriptors on)

    def setup(self, message, fds):
        """A channel's schema (message: its pickled request, read) and, where given, its arenas'
        descriptors (plain first, then oracle), mapped read-only and closed."""
        try:
            state = self.channels.setdefault(message["channel"], {"maps": {}, "seq": 0})
            state["schema"], state["version"] = Schema(**message["schema"]), message["version"]
            state["forms"] = {kind: _forms(columns) for kind, columns in state["schema"].columns.items()}
            state["plan"] = _plan(state["schema"])
            for kind, fd in zip(("plain", "oracle"), fds):
                old = state["maps"].pop(kind, None)
                if old is not None:
                    old.close()
                state["maps"][kind] = mmap.mmap(fd, os.fstat(fd).st_size, mmap.MAP_SHARED, mmap.PROT_READ)
        finally:
            for fd in fds:
                os.close(fd)

    def context(self, data):
        """(sequence number, ctx) of a step's request: its arenas copied out, then read."""
        _, channel, seq = REQUEST.unpack(data)
        state = self.channels.get(channel)
        if state is None:
            raise StaleStep(f"a step of channel {channel}, which was never set up")
        if seq <= state["seq"]:
            raise StaleStep(f"a step's request of sequence number {seq}, not newer than the last read ({state['seq']})")
        schema, columns = state["schema"], {}
        for kind, mm in state["maps"].items():
            columns[kind] = _copied(mm, state["forms"][kind], seq, state["version"])
        state["seq"] = seq
        return seq, _context(state["plan"], schema, columns, *_index(state["maps"]["plain"]))


def _index(mm):
    return HEAD.unpack_from(mm, 0)[1:3]


def _forms(columns):
    """(dtypes, trailing shapes) of an arena's columns [(dtype, trailing shape)]."""
    return [np.dtype(d) for d, _ in columns], [tuple(shape) for _, shape in columns]


def _copied(mm, forms, seq, version):
    """The arrays of one arena (forms: its columns', _forms), from one copy of the bytes it uses
    (its own, writable), each a view of the copy (arena_views)."""
    dtypes, shapes = forms
    head_seq, _, _, n, held_version, used = HEAD.unpack_from(mm, 0)
    if head_seq != seq or n != len(dtypes) or held_version != version or used > len(mm):
        raise StaleStep(f"a step's request of sequence number {seq}; its arena holds {head_seq}")
    buf = np.frombuffer(mm, np.uint8, used).copy()
    if HEAD.unpack_from(buf, 0)[0] != seq:   # (the copy is of the step asked for)
        raise StaleStep(f"the arena moved on from sequence number {seq} while it was read")
    try:
        return arena_views(buf, HEAD.size, dtypes, shapes)
    except ValueError:
        raise StaleStep(f"the arena of sequence number {seq} holds columns past the bytes it uses") from None


SLOTS = ("bodies", "contacts", "problem.bodies", "problem.contacts", "problem", "ctx", "previous", "reference")


def _plan(schema):
    """[(names, positions)] of a schema, one a slot (SLOTS): each table's names in the order of
    its entries and the position of each one's column among the plain arena's columns followed
    by the oracle's (arena_tables)."""
    plain = len(schema.columns.get("plain", ()))
    slots = {slot: ([], []) for slot in SLOTS}
    for slot, name, kind, column in schema.entries:
        names, at = slots[slot]
        names.append(name)
        at.append(column if kind == "plain" else plain + column)
    return [(tuple(names), tuple(at)) for names, at in slots.values()]


def _kinds():
    """(Solution, StepProblem, StepContext, KeyedImpulses), imported on a contestant's first step
    (not with this module: the judge's side needs none of them), then held: an import in the
    function would look each up again, a few microseconds a step."""
    global _KINDS
    if _KINDS is None:
        from ..solver.pgs import Solution
        from ..solver.problem import StepProblem
        from ..warmstart.starts import StepContext
        from .keyed import KeyedImpulses
        _KINDS = (Solution, StepProblem, StepContext, KeyedImpulses)
    return _KINDS


_KINDS = None


def _context(plan, schema, columns, index, problem_index):
    """The StepContext the arrays make, as the judge's visible ctx held them."""
    Solution, StepProblem, StepContext, KeyedImpulses = _kinds()
    tables = dict(zip(SLOTS, arena_tables(columns["plain"] + columns.get("oracle", []), plan)))
    problem_scalars, ctx_scalars = (dict(s) for s in schema.scalars)
    problem = StepProblem(bodies=tables["problem.bodies"], contacts=tables["problem.contacts"], index=problem_index,
                          **problem_scalars, **{k: tables["problem"].get(k) for k in PROBLEM_ARRAYS})
    reference = None
    if tables["reference"]:
        rest = pickle.loads(tables["reference"].pop("").tobytes())
        reference = Solution(**tables["reference"], **rest)
    previous = KeyedImpulses(tables["previous"]["keys"], tables["previous"]["normal"], tables["previous"]["tangent"])
    return StepContext(problem=problem, bodies=tables["bodies"], contacts=tables["contacts"], reference=reference,
                       persisted=tables["ctx"]["persisted"], previous=previous, index=index, **ctx_scalars)
