"""The closed loop's path to its contestants: contact keys matched as arrays (contest/keyed.py)."""
import copy
import pickle

import numpy as np

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


def test_keys_that_differ_in_any_column_or_repeat_are_told_apart():
    rng = np.random.default_rng(4)
    before = rng.integers(-2, 2, (3000, 5))   # (most of the 1,024 keys, many twice: the first row kept)
    now = np.concatenate((rng.integers(-2, 3, (2000, 5)), before[:10] + np.eye(5, dtype=np.int64)[np.arange(10) % 5]))
    now[:3] = [2 ** 62, -2 ** 62, 0, 0, 2 ** 63 - 1], [0, 0, 0, 0, 0], [-1, -1, -1, -1, -1]
    found, row = KeySet(before).find(now)
    assert np.array_equal(found, _by_tuples(before, now)) and found.any() and not found.all()
    assert np.array_equal(before[row[found]], now[found])
    first = {}
    for i, k in enumerate(map(tuple, before.tolist())):
        first.setdefault(k, i)
    assert [first[k] for k in map(tuple, now[found].tolist())] == row[found].tolist()
    assert not KeySet().find(now)[0].any() and len(KeySet(before).find(np.zeros((0, 5)))[0]) == 0


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


# --- The step's context through shared memory (contest/arena.py) ------------------------------------

import dataclasses  # noqa: E402
import textwrap  # noqa: E402

from hypothesis import example, given, settings, strategies as st  # noqa: E402
import pytest  # noqa: E402

from deepcontact.contest import arena  # noqa: E402
from deepcontact.contest.arena import Mapped, StepChannel  # noqa: E402
from deepcontact.contest.wire import unpack, pack  # noqa: E402
from deepcontact.evaluate.replay import visible_context  # noqa: E402
from deepcontact.plugins import PluginError  # noqa: E402
from deepcontact.scene.generators import generate  # noqa: E402
from deepcontact.simulate import stepping  # noqa: E402
from deepcontact.simulate.engines import Box2D  # noqa: E402
from deepcontact.simulate.pgs_loop import PGSStepper  # noqa: E402
from deepcontact.solver.reference import reference_solution  # noqa: E402
from deepcontact.solver.settings import SolveSettings  # noqa: E402
from deepcontact.warmstart.starts import StepContext, described  # noqa: E402


@pytest.fixture(scope="module")
def steps():
    """Two consecutive steps of a settling pile as the loop poses them: (bodies, contacts, problem)."""
    scene = generate("pile", 0, {"count": 30, "box": 16.0, "sigma": 4.0})
    caught = []

    def start_fn(bodies, contacts, problem, builtin_n, builtin_t):
        problem.start_normal, problem.start_tangent = builtin_n, builtin_t
        caught.append((bodies, contacts, problem))
        return builtin_n, builtin_t
    looped(scene, start_fn, 120)
    return caught[-2:]


def looped(scene, start_fn, steps):
    """The scene stepped `steps` times by the loop, start_fn asked each step (as the closed loop asks)."""
    engine = Box2D(solver=SolveSettings(), start="builtin", start_fn=start_fn)
    world = engine.build(scene)
    stepper = PGSStepper(world, scene, engine.solver, "builtin", start_fn=start_fn, record=False)
    for _ in stepping.steps(world, scene, stepper.step, steps):
        pass


def step_ctx(step, traits, label="probe", previous=None):
    """The ctx of a step as the loop's _Adapter makes it, as a start of `traits` may see it."""
    bodies, contacts, problem = step
    keys = np.ascontiguousarray(problem.keys)
    ctx = StepContext(problem=problem, bodies=bodies, contacts=contacts,
                      reference=reference_solution(problem) if traits["needs_reference"] else None,
                      persisted=np.arange(len(keys)) % 2 == 0, index=int(problem.index) + 7, variant=label,
                      previous=previous if previous is not None else KeyedImpulses(keys[:3], [1.0, 2, 3], [0.5, 0, 0]),
                      trajectory="loop")
    return visible_context(ctx, traits, label)


def same(a, b, where="ctx"):
    if isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), where
    elif dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for k in a:
            same(a[k], b[k], f"{where}[{k!r}]")
    else:
        assert a == b, (where, a, b)



def test_the_loops_problem_is_the_one_from_arrays_poses(steps):
    from deepcontact.solver.problem import StepProblem
    for bodies, contacts, problem in steps:
        posed = StepProblem.from_arrays(bodies, contacts, dt=problem.dt, gravity=problem.gravity,
                                        block_solve=problem.block_solve,
                                        velocity_iterations=problem.velocity_iterations)
        posed.start_normal, posed.start_tangent = problem.start_normal, problem.start_tangent   # (the loop's)
        same(problem, posed, "problem")
        assert problem.contacts["row_a"].dtype == np.int32 and len(problem.keys) == problem.points


@pytest.mark.parametrize("spec, params, removed", [
    ("pyramid", {"base": 6}, [(20, 5), (40, 21)]),   # (boxes: 2-point manifolds; a middle body, then the last)
    ("pile", {"count": 30, "box": 16.0, "sigma": 4.0}, [(30, 30), (50, 1)]),   # (the last body first)
])
def test_the_loops_problem_is_the_one_from_arrays_poses_on_boxes_and_with_bodies_removed(spec, params, removed):
    """_from_world's problem, each step through removals (rows by index only while the bodies
    are every index from 0; found by search once one in the middle is gone), is from_arrays' on
    the same columns, and its rows name the contacts' bodies."""
    from deepcontact.scene.model import RemoveEvent
    from deepcontact.solver.problem import StepProblem
    scene = generate(spec, 0, params)
    scene.events = [RemoveEvent(step=k, body=b) for k, b in removed]
    seen = {"fast": 0, "searched": 0, "two points": 0}

    def start_fn(bodies, contacts, problem, builtin_n, builtin_t):
        posed = StepProblem.from_arrays(bodies, contacts, dt=scene.dt, gravity=scene.effects.gravity,
                                        block_solve=scene.solver.block_solve,
                                        velocity_iterations=problem.velocity_iterations)
        posed.start_normal, posed.start_tangent = problem.start_normal, problem.start_tangent
        same(problem, posed, "problem")
        index = bodies["index"]
        assert np.array_equal(index[problem.contacts["row_a"]], contacts["body_a"])
        assert np.array_equal(index[problem.contacts["row_b"]], contacts["body_b"])
        seen["fast" if np.array_equal(index, np.arange(len(index))) else "searched"] += 1
        seen["two points"] += int(np.any(contacts["point_count"] == 2))
        return builtin_n, builtin_t
    looped(scene, start_fn, 60)
    assert seen["fast"] and seen["searched"], seen
    assert seen["two points"] or spec == "pile", seen


def read_back(channel, request, mapped, receiver="reader"):
    schema, fds = channel.setup_for(receiver)
    if schema is not None:
        mapped.setup(pickle.loads(schema), fds)
    return mapped.context(request)


@pytest.mark.parametrize("oracle", [False, True])
def test_a_contestant_reads_the_ctx_the_judge_wrote(steps, oracle):
    traits = dict(described("builtin"), needs_reference=oracle, needs_recorded=oracle)
    channel, mapped = StepChannel(oracle), Mapped()
    try:
        for step in steps:   # (two steps: the second through the schema already held)
            ctx = step_ctx(step, traits)
            seq, got = read_back(channel, channel.write(ctx), mapped)
            assert seq == channel.seq
            same(dataclasses.replace(ctx, previous=dict(ctx.previous)), dataclasses.replace(got, previous=dict(got.previous)))
            assert got.problem.contacts["friction"] is got.contacts["friction"]   # (shared as the judge's were)
            assert (got.reference is not None) == oracle and ("normal_impulse" in got.contacts) == oracle
            got.problem.start_normal[:] = -1.0   # (its own copy: writable, and nothing the judge holds)
            assert not np.any(ctx.problem.start_normal == -1.0)
        assert set(channel.arenas) == ({"plain", "oracle"} if oracle else {"plain"})
    finally:
        channel.close()


def test_an_ordinary_channel_refuses_what_only_an_oracle_may_see(steps):
    ctx = step_ctx(steps[0], dict(described("builtin"), needs_reference=True))
    channel = StepChannel(False)
    try:
        with pytest.raises(ValueError, match="only an oracle"):
            channel.write(ctx)
    finally:
        channel.close()


def test_a_step_larger_than_its_arena_hands_the_reader_a_new_one(steps, monkeypatch):
    monkeypatch.setattr(arena, "LEAST", 4096)
    channel, mapped = StepChannel(False), Mapped()
    try:
        ctx = step_ctx(steps[0], described("builtin"))
        small = dataclasses.replace(ctx, previous=KeyedImpulses())
        read_back(channel, channel.write(small), mapped)
        first = channel.arenas["plain"].generation
        big = dataclasses.replace(ctx, previous=KeyedImpulses(np.zeros((4000, 5), np.int64), np.ones(4000), np.ones(4000)))
        _, got = read_back(channel, channel.write(big), mapped)
        assert channel.arenas["plain"].generation > first and len(got.previous._arrays[0]) == 4000
    finally:
        channel.close()


class _BothWays:
    """A loop's start_fn that writes each posed step both ways, the ctx made in Python (write) and
    straight from the world (write_world), into channels of its own, and compares their bytes."""

    def __init__(self, scene, traits):
        from deepcontact.contest.keyed import KeySet
        self.scene, self.traits, self.known, self.previous = scene, traits, KeySet(), KeyedImpulses()
        self.ctx_way, self.world_way = StepChannel(False), StepChannel(False)
        self.compared, self.refused, self.rng = 0, 0, np.random.default_rng(5)

    def __call__(self, *args):
        raise AssertionError("every posed step comes through from_world here")

    def from_world(self, world, carried, points):
        from deepcontact.contest.keyed import KeySet
        from deepcontact.solver.problem import StepProblem
        bodies, contacts = world.bodies(), world.contacts()
        start_n, start_t = carried * contacts["normal_impulse"], carried * contacts["tangent_impulse"]
        problem = StepProblem._from_world(bodies, contacts, dt=self.scene.dt, gravity=self.scene.effects.gravity,
                                          block_solve=self.scene.solver.block_solve, velocity_iterations=8)
        problem.start_normal, problem.start_tangent = start_n, start_t
        ctx = visible_context(StepContext(problem=problem, bodies=bodies, contacts=contacts, reference=None,
                                          persisted=self.known.find(problem.keys)[0], previous=self.previous,
                                          index=0, variant="v", trajectory="loop"), self.traits, "v")
        self.ctx_way.write(ctx)
        if self.world_way.schema is None:
            self.world_way.write(ctx)
        else:
            done = self.world_way.write_world(world, carried, self.known.keys, self.previous, (0, 0))
            if done is None:
                self.refused += 1
            else:
                assert np.array_equal(done[1], problem.keys) and done[1].dtype == np.int64
                a, b = (channel.arenas["plain"].map for channel in (self.ctx_way, self.world_way))
                head_a, head_b = arena.HEAD.unpack_from(a, 0), arena.HEAD.unpack_from(b, 0)
                assert head_a[1:] == head_b[1:], (head_a, head_b)   # (the same index, columns, schema, bytes)
                assert a[arena.HEAD.size:head_a[-1]] == b[arena.HEAD.size:head_b[-1]]
                self.compared += 1
        self.known = KeySet(problem.keys)
        # (a solution of the step, to be the next step's previous: values of its own)
        self.previous = KeyedImpulses(problem.keys, self.rng.random(points), self.rng.normal(size=points))
        return start_n.astype(np.float64), start_t.astype(np.float64)

    def close(self):
        self.ctx_way.close()
        self.world_way.close()


@pytest.mark.parametrize("spec, params, removed, least", [
    ("pile", {"count": 30, "box": 16.0, "sigma": 4.0}, [], 1 << 20),
    ("pile", {"count": 30, "box": 16.0, "sigma": 4.0}, [(30, 30), (50, 1)], 4096),   # (rows searched; arenas grown)
    ("pyramid", {"base": 6}, [(20, 5), (40, 21)], 1 << 20),   # (boxes: two-point manifolds, static ground)
])
def test_a_step_written_from_the_world_is_the_bytes_its_ctx_writes(spec, params, removed, least, monkeypatch):
    """write_world's arena holds, byte for byte, what write puts there of the ctx the judge makes
    in Python: every column, shared as before, through removals and an arena made larger."""
    from deepcontact.scene.model import RemoveEvent
    from deepcontact.simulate import pgs_loop
    monkeypatch.setattr(arena, "LEAST", least)
    scene = generate(spec, 0, params)
    scene.events = [RemoveEvent(step=k, body=b) for k, b in removed]
    # (the world's bodies are read after the step is posed, where the ctx's were read before: the
    # pose moves none of what they hold)
    pose = pgs_loop.pgs_pose

    def posed(world, settings):
        before = world.bodies()
        points = pose(world, settings)
        same(before, world.bodies(), "bodies")
        return points
    monkeypatch.setattr(pgs_loop, "pgs_pose", posed)
    both = _BothWays(scene, described("builtin"))
    try:
        looped(scene, both, 70)
        grown = both.world_way.arenas["plain"].generation
    finally:
        both.close()
    assert both.compared > 30 and both.refused == 0, (both.compared, both.refused)
    assert grown > 1 or least > 4096



DIGEST = textwrap.dedent('''
    import zlib
    import numpy as np
    from deepcontact.warmstart.starts import StartValue

    class Digest:
        """A start whose answer turns on every column of its ctx and on its scalars: Box2D's warm
        start, scaled by a number a digest of them all makes, the persisted points' kept."""
        def __call__(self, ctx):
            p, h = ctx.problem, 0
            for table in (ctx.bodies, ctx.contacts, p.bodies, p.contacts):
                for k in sorted(table):
                    h = zlib.crc32(k.encode() + np.ascontiguousarray(table[k]).tobytes(), h)
            for a in (p.start_normal, p.start_tangent, p.keys, ctx.persisted):
                h = zlib.crc32(np.ascontiguousarray(a).tobytes(), h)
            h = zlib.crc32(repr((sorted(dict(ctx.previous).items()), ctx.index, p.index, p.dt, p.gravity,
                                 p.block_solve, p.velocity_iterations, ctx.variant, ctx.trajectory)).encode(), h)
            scale = 0.5 + (h % 1000) / 1000
            normal = np.where(ctx.persisted, p.start_normal, 0.0) * scale
            return StartValue(normal.astype(np.float64), np.asarray(p.start_tangent, np.float64), {})
    ''')


def test_the_loop_through_the_world_written_step_is_the_loop_through_the_ctx(tmp_path, monkeypatch):
    """The closed loop's steps written from the world (its _Adapter's from_world) give a start
    whose answer turns on its whole ctx what the ctx written in Python gives it, step by step:
    the same trajectory, iterations and residuals, through removals and an arena made larger."""
    from deepcontact.evaluate import closed_loop
    from deepcontact.evaluate.replay import variants
    from deepcontact.scene.model import RemoveEvent
    from deepcontact.warmstart.starts import STARTS, make_starts
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "ctx_digest.py").write_text(DIGEST)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    monkeypatch.setattr(arena, "LEAST", 4096)
    scene = generate("pile", 0, {"count": 30, "box": 16.0, "sigma": 4.0})
    scene.events = [RemoveEvent(step=40, body=5), RemoveEvent(step=50, body=0)]
    taken = []
    from_world = closed_loop._Adapter.from_world

    def counted(self, *args):
        start = from_world(self, *args)
        taken.append(start is not None)
        return start
    runs = {}
    try:
        v = variants(make_starts(["ctx_digest:Digest"]))[0]
        for way in ("world", "ctx"):
            if way == "world":
                monkeypatch.setattr(closed_loop._Adapter, "from_world", counted)
            else:
                monkeypatch.delattr(closed_loop._Adapter, "from_world")
            runs[way] = closed_loop._interleaved(scene, [(v, SolveSettings(), False)], 80)[0][0]
    finally:
        import sys
        sys.modules.pop("ctx_digest", None)
        STARTS._loaded.pop("ctx_digest:Digest", None)
    assert sum(taken) > 40 and not all(taken), taken   # (the first step with points made the schema)
    a, b = runs["world"], runs["ctx"]
    assert np.array_equal(a.iterations, b.iterations) and np.array_equal(a.residuals, b.residuals, equal_nan=True)
    assert len(a.positions) == len(b.positions) == 80
    assert all(np.array_equal(p.index, q.index) and np.array_equal(p.array, q.array) for p, q in zip(a.positions, b.positions))

def test_a_step_the_world_cannot_write_is_left_to_the_ctx(steps):
    """An oracle's channel, one with no schema yet, and a world whose bodies are not finite get
    None from write_world: the judge writes the ctx, which says what is wrong. And no column the
    world writes is one only an oracle may see: none is named, none is written by its code."""
    from deepcontact._box2d import arena_put_world, world_columns
    assert not any(arena._is_oracle(slot, name) for slot, name, *_ in world_columns())
    fields = [name for slot, name, *_ in world_columns() if slot == "contacts"]
    assert "normal_impulse" not in fields and "start_normal_impulse" in fields
    scene = generate("pile", 0, {"count": 30, "box": 16.0, "sigma": 4.0})
    world = Box2D().build(scene)
    for _ in range(30):
        world.step(scene.dt, 8, 3)
    plain, oracle = StepChannel(False), StepChannel(True)
    try:
        keys = np.zeros((0, 5), np.int64)
        assert plain.write_world(world, np.float32(1), keys, KeyedImpulses(), (0, 0)) is None   # (no schema yet)
        traits = dict(described("builtin"), needs_reference=True)
        oracle.write(step_ctx(steps[0], traits))
        assert oracle.write_world(world, np.float32(1), keys, KeyedImpulses(), (0, 0)) is None
        plain.write(step_ctx(steps[0], described("builtin")))
        seq = plain.seq
        assert plain.write_world(world, np.float32(1), keys, KeyedImpulses(), (0, 0)) is not None and plain.seq == seq + 1
        index = world.bodies()["index"]
        world.set_body_state(index[:1], np.full((1, 2), np.nan, np.float32), np.zeros(1, np.float32),
                             np.zeros((1, 2), np.float32), np.zeros(1, np.float32))
        assert plain.write_world(world, np.float32(1), keys, KeyedImpulses(), (0, 0)) is None and plain.seq == seq + 1
        recorded = 100 + 25   # (the contacts' normal_impulse, the 26th of their fields: native/records.hpp)
        with pytest.raises(ValueError, match="no column has the code 125"):
            arena_put_world(world, bytearray(1 << 16), 48, np.array([recorded], np.int64), 1.0, keys, keys,
                            np.zeros(0), np.zeros(0))
    finally:
        plain.close()
        oracle.close()


def test_a_stale_sequence_number_is_refused(steps):
    channel, mapped = StepChannel(False), Mapped()
    try:
        old = channel.write(step_ctx(steps[0], described("builtin")))
        read_back(channel, old, mapped)
        with pytest.raises(arena.StaleStep, match="not newer"):
            mapped.context(old)   # (the same step again)
        new = channel.write(step_ctx(steps[1], described("builtin")))
        ahead = arena.REQUEST.pack(arena.STEP, channel.ident, channel.seq + 1)
        with pytest.raises(arena.StaleStep, match="its arena holds"):
            mapped.context(ahead)   # (a step the arena does not hold)
        assert mapped.context(new)[0] == channel.seq
    finally:
        channel.close()


def test_an_answer_is_copied_out_before_it_is_checked():
    data = bytearray(pack({"seconds": {}}, {"normal": np.ones(4), "tangent": np.zeros(4)}))
    _, arrays = unpack(data, "the variant 'x'")
    data[-64:] = bytes(64)   # (the bytes it came in, changed after it was read)
    assert np.array_equal(arrays["normal"], np.ones(4))
    assert not any(np.shares_memory(a, np.frombuffer(data, np.uint8)) for a in arrays.values())



@pytest.mark.parametrize("head", [
    b'{"seconds": {}, "seq": 7, "arrays": [["normal", 3], ["tangent", 3]]}',
    b'{"seconds": {}, "seq": 0, "arrays": [["normal", 0], ["tangent", 0]]}',
    b'{"seconds": {}, "seq": 999999999999999999, "arrays": [["normal", 3], ["tangent", 3]]}',
    b'{"seconds": {}, "seq": 9999999999999999999, "arrays": [["normal", 3], ["tangent", 3]]}',   # (past int64)
    b'{"seconds": {}, "seq": 07, "arrays": [["normal", 3], ["tangent", 3]]}',    # (no JSON number)
    b'{"seconds": {}, "seq": -1, "arrays": [["normal", 3], ["tangent", 3]]}',
    b'{"seconds": {}, "seq": 7, "arrays": [["normal", 3], ["tangent", 2]]}',
    b'{"seconds": {}, "seq": 7, "arrays": [["normal", 3], ["normal", 3]]}',
    b'{"seconds": {}, "seq": 7, "arrays": [["normal", 3], ["tangent", 3]], "x": 1}',
    b'{"seconds": {}, "seq": 7.0, "arrays": [["normal", 3], ["tangent", 3]]}',
])
def test_a_step_answer_read_without_the_parser_is_what_the_parser_reads(head, monkeypatch):
    from deepcontact.contest import wire
    body = np.arange(6, dtype=np.float64).tobytes()
    data = len(head).to_bytes(4, "little") + head + body

    def read():
        try:
            header, arrays = unpack(data, "the variant 'x'")
            return header, {k: v.tolist() for k, v in arrays.items()}
        except PluginError as e:
            return "refused", str(e).split(" (")[0]
    fast = read()
    monkeypatch.setattr(wire, "_STEP_ANSWER", __import__("re").compile(b"(?!)"))   # (every header parsed)
    assert read() == fast


def test_step_answers_mutated_at_random_are_read_as_the_parser_reads_them(monkeypatch):
    """The guest's own step answers, a byte or a few changed, inserted or dropped (and a length
    or a tail off): the header read without the parser gives what the parser gives, the same
    header and arrays or the same refusal, on every one (a seeded sample; about a quarter still
    the guest's form)."""
    import random
    import re
    from deepcontact.contest import wire
    fast, parsed = wire._STEP_ANSWER, re.compile(b"(?!)")
    rng = random.Random(5)

    def read(data, form):
        monkeypatch.setattr(wire, "_STEP_ANSWER", form)
        try:
            header, arrays = unpack(data, "the variant 'x'")
            return header, {k: v.tobytes() for k, v in arrays.items()}
        except PluginError:
            return "refused"
    matched = 0
    for _ in range(4000):
        n = rng.choice([0, 1, 3])
        seq = rng.choice([0, 7, 10 ** 17, 10 ** 18 - 1, 10 ** 18, 2 ** 63 - 1, 2 ** 63])
        head = bytearray(f'{{"seconds": {{}}, "seq": {seq}, "arrays": [["normal", {n}], '
                         f'["tangent", {rng.choice([n, n + 1])}]]}}'.encode())
        for _ in range(rng.choice([0, 1, 1, 2, 3])):
            at = rng.randrange(len(head))
            [head.__delitem__, lambda k: head.insert(k, rng.choice(b'07 {}[]",:-.e\\u')),
             lambda k: head.__setitem__(k, rng.choice(b'19 {}[]",:-.'))][rng.randrange(3)](at)
        size = len(head) + rng.choice([0] * 18 + [-1, 8])
        data = size.to_bytes(4, "little") + bytes(head) + np.arange(2 * n + 1.0).tobytes()[:8 * rng.choice([2 * n, 2 * n + 1])]
        matched += fast.fullmatch(data, 4, 4 + size) is not None
        assert read(data, fast) == read(data, parsed), data
    assert 500 < matched < 3500, matched


@pytest.mark.parametrize("header, arrays", [
    ({"seconds": {}, "seq": 7}, {"normal": np.arange(3.0), "tangent": -np.arange(3.0)}),
    ({"seconds": {}, "seq": 0}, {"normal": np.zeros(0), "tangent": np.zeros(0)}),
    ({"seconds": {}, "seq": 2 ** 62}, {"normal": np.ones(2, np.float32), "tangent": [0.5, 1]}),
    ({"seconds": {"net": 0.25}, "seq": 7}, {"normal": np.ones(1), "tangent": np.ones(1)}),
    ({"seq": 7, "seconds": {}}, {"normal": np.ones(1), "tangent": np.ones(1)}),
    ({"seconds": {}, "seq": True}, {"normal": np.ones(1), "tangent": np.ones(1)}),
    ({"seconds": {}, "seq": 7}, {"tangent": np.ones(1), "normal": np.ones(1)}),
])
def test_a_step_answer_packed_without_json_is_the_bytes_json_writes(header, arrays):
    import json
    import struct
    columns = {k: np.ascontiguousarray(v, np.float64) for k, v in arrays.items()}
    head = json.dumps(dict(header, arrays=[[k, int(v.size)] for k, v in columns.items()])).encode()
    assert pack(header, arrays) == struct.pack("<I", len(head)) + head + b"".join(v.tobytes() for v in columns.values())


_VALUES = st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-320, -1e-320, 1e308, -1e308, np.inf, -np.inf, np.nan])


@settings(max_examples=400, deadline=None)
@given(pairs=st.lists(st.tuples(_VALUES, _VALUES), max_size=4), tangent=st.sampled_from(["as drawn", "one more", "none"]))
@example(pairs=[(1.0, np.inf)], tangent="as drawn").via("each fault alone")
@example(pairs=[(1.0, -np.inf)], tangent="as drawn").via("each fault alone")
@example(pairs=[(1.0, np.nan)], tangent="as drawn").via("each fault alone")
@example(pairs=[(np.inf, 0.0)], tangent="as drawn").via("each fault alone")
@example(pairs=[(-np.inf, 0.0)], tangent="as drawn").via("each fault alone")
@example(pairs=[(np.nan, 0.0)], tangent="as drawn").via("each fault alone")
@example(pairs=[(-1e-320, 0.0)], tangent="as drawn").via("each fault alone")
@example(pairs=[(np.nan, 0.0)], tangent="one more").via("a non-finite normal before a tangent of another shape")
@example(pairs=[(-1.0, 0.0)], tangent="none").via("a pull after a missing tangent")
@example(pairs=[(1e308, 1e308), (1e308, -1e308)], tangent="as drawn").via("a sum that would overflow")
def test_an_answer_is_refused_exactly_where_a_value_is_not_finite_or_a_normal_pulls(pairs, tangent):
    # checked_answer reads an answer in one native pass: it must refuse what a look at each array
    # in turn refuses (its shape, then its values; then a pull), with the same line, and nothing else
    from deepcontact.contest.wire import checked_answer
    n = len(pairs)
    arrays = {k: np.array([p[i] for p in pairs], np.float64) for i, k in enumerate(("normal", "tangent"))}
    if tangent == "one more":
        arrays["tangent"] = np.append(arrays["tangent"], 0.0)
    elif tangent == "none":
        del arrays["tangent"]
    expected = None
    for what in ("normal", "tangent"):
        a = arrays.get(what)
        if a is None or a.shape != (n,):
            expected = f"answered {what} impulses of shape"
            break
        if not all(np.isfinite(a)):
            expected = f"answered a non-finite {what} impulse"
            break
    if expected is None and any(v < 0 for v in arrays["normal"]):
        expected = "answered a negative normal impulse"
    if expected is None:
        out = checked_answer("v", arrays, n)
        assert out[0] is arrays["normal"] and out[1] is arrays["tangent"]
    else:
        with pytest.raises(PluginError, match=expected):
            checked_answer("v", arrays, n)

PROBE = textwrap.dedent('''
    import ctypes, gc, mmap
    import numpy as np
    from deepcontact.warmstart.starts import StartValue

    def _maps():
        from deepcontact.contest.arena import Mapped
        return [m for o in gc.get_objects() if isinstance(o, Mapped)
                for state in o.channels.values() for m in state["maps"].values()]

    def _probe():
        """What this process can do to the arenas it was handed: 1.0 where a write got through."""
        out = {"arenas": 0.0, "oracle_arenas": 0.0, "item_write": 0.0, "mprotect_write": 0.0}
        text = open("/proc/self/maps").read()
        out["arenas"] = float(text.count("dc-arena"))
        out["oracle_arenas"] = float(text.count("dc-oracle-arena"))
        libc = ctypes.CDLL(None, use_errno=True)
        libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
        for m in _maps():
            try:
                m[0] = 1
                out["item_write"] = 1.0
            except TypeError:
                pass
            address = np.frombuffer(m, np.uint8).ctypes.data
            if libc.mprotect(address, len(m), mmap.PROT_READ | mmap.PROT_WRITE) == 0:
                out["mprotect_write"] = 1.0
        return out

    class Probe:
        """Box2D's warm start, after trying to write the arenas its ctx came in."""
        def __call__(self, ctx):
            return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), _probe())

    class OracleProbe(Probe):
        """The same, as an oracle (it asks for the step's reference)."""
        needs_reference = True
''')


@pytest.fixture
def probes(tmp_path, monkeypatch):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "arena_probe.py").write_text(PROBE)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    yield
    import sys
    from deepcontact.warmstart.starts import STARTS
    sys.modules.pop("arena_probe", None)
    for name in ("arena_probe:Probe", "arena_probe:OracleProbe"):
        STARTS._loaded.pop(name, None)


def probed(step, name):
    """(the probe's findings, the judge's arena bytes before and after its call, its answer)."""
    from deepcontact.contest.client import Contestant
    from deepcontact.warmstart.starts import make_starts
    start = make_starts([name])[name]
    contestant = Contestant(name, name, start).begin()
    channel = StepChannel(contestant.traits["needs_reference"])
    try:
        request = channel.write(step_ctx(step, contestant.traits, name))
        before = {k: bytes(a.map) for k, a in channel.arenas.items()}
        _, header, arrays = contestant.call_step(channel, request, 60)
        after = {k: bytes(a.map) for k, a in channel.arenas.items()}
        return header["seconds"], before, after, arrays
    finally:
        contestant.close()
        channel.close()


def test_a_contestant_cannot_write_the_arena(steps, probes):
    found, before, after, arrays = probed(steps[0], "arena_probe:Probe")
    assert found["arenas"] >= 1, found   # (it was handed the arena, mapped)
    assert found["item_write"] == 0 and found["mprotect_write"] == 0, found
    assert before == after   # (the judge's copy unchanged)
    assert np.array_equal(arrays["normal"], steps[0][2].start_normal)


def test_an_ordinary_start_never_gets_the_oracles_arena(steps, probes):
    ordinary = probed(steps[0], "arena_probe:Probe")[0]
    oracle, before, after, _ = probed(steps[0], "arena_probe:OracleProbe")
    assert ordinary["arenas"] >= 1 and ordinary["oracle_arenas"] == 0, ordinary
    assert oracle["oracle_arenas"] >= 1 and oracle["mprotect_write"] == 0 and before == after, oracle


def test_the_null_contestant_reads_the_step_as_the_variant_does_and_a_stale_answer_is_refused(steps):
    from deepcontact.contest.client import Contestant
    null, channel = Contestant.null(), StepChannel(False)
    try:
        request = channel.write(step_ctx(steps[0], described("builtin")))
        _, header, arrays = null.call_step(channel, request, 60)
        assert header["seq"] == channel.seq and np.array_equal(arrays["normal"], np.zeros(steps[0][2].points))
        request = channel.write(step_ctx(steps[1], described("builtin")))
        channel.seq += 1   # (the judge now waits for a later step than the one its contestant reads)
        with pytest.raises(PluginError, match="answered step"):
            null.call_step(channel, request, 60)
    finally:
        null.close()
        channel.close()


def test_a_descriptor_of_the_arena_opened_again_cannot_write_it(steps):
    import mmap
    import os
    channel = StepChannel(False)
    try:
        plain = channel.arenas["plain"]
        channel.write(step_ctx(steps[0], described("builtin")))
        before = bytes(plain.map)
        reader = plain.reader()
        again = os.open(f"/proc/self/fd/{reader}", os.O_RDWR)   # (by the inode's mode: allowed)
        try:
            assert plain.sealed
            with pytest.raises(PermissionError):
                mmap.mmap(again, plain.size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
            with pytest.raises(PermissionError):
                os.pwrite(again, b"\xff" * 64, 0)
            with pytest.raises(OSError):
                os.ftruncate(again, 0)
            private = mmap.mmap(reader, plain.size, mmap.MAP_PRIVATE, mmap.PROT_READ | mmap.PROT_WRITE)
            private[:64] = b"\xff" * 64   # (its own copy of the page: never the judge's)
            private.close()
        finally:
            os.close(again)
            os.close(reader)
        assert bytes(plain.map) == before
    finally:
        channel.close()


# --- The arena's native functions held to their buffers (contest/arena.py, native/module.cpp) ---------

ARENA_ABUSE = textwrap.dedent('''
    import numpy as np
    from deepcontact._box2d import arena_put, arena_tables, arena_views
    from deepcontact.contest.arena import HEAD, _forms_of

    def tried(name, call):
        try:
            call()
            print(name, "accepted", flush=True)
        except Exception as e:
            print(name, type(e).__name__, flush=True)

    step = [np.arange(4.0)]
    tried("head past the arena", lambda: arena_put(bytearray(4096), 2 ** 64 - 8, step, _forms_of(step)))
    guard = np.zeros(1 << 16, np.uint8)
    big = [np.full(200, 7.0)]
    tried("reversed arena", lambda: arena_put(guard[:4096][::-1], HEAD.size, big, _forms_of(big)))
    print("beyond the reversed arena", "written" if guard[4096:].any() else "untouched")
    huge = [np.broadcast_to(np.zeros(1), (2 ** 32 - 1, 2 ** 20))]   # (its copy: 32 PiB)
    tried("a column no copy fits", lambda: arena_put(bytearray(1 << 20), HEAD.size, huge, _forms_of(huge)))
    mine = [np.array([object(), object()])]
    tried("objects written", lambda: arena_put(bytearray(4096), HEAD.size, mine, _forms_of(mine)))
    copy = np.full(4096, 0x41, np.uint8)
    copy[HEAD.size:HEAD.size + 4] = [2, 0, 0, 0]
    tried("objects read", lambda: arena_views(copy, HEAD.size, [np.dtype(object)], [()]))
    tried("head past the copy", lambda: arena_views(copy, 2 ** 64 - 4, [np.dtype("f8")], [()]))
    tried("a shape past any size", lambda: arena_views(copy, HEAD.size, [np.dtype("u1")], [(2 ** 62, 8)]))

    class Name(str):
        def __hash__(self):   # (Python code run mid-call: the columns it reads emptied)
            columns.clear()
            return str.__hash__(self)
    columns = [np.arange(3.0), np.arange(2.0)]
    tried("a name that empties the columns", lambda: arena_tables(columns, [((Name("a"), "b"), (0, 1))]))
''')


def test_the_arenas_native_functions_never_touch_memory_past_their_buffers():
    """A hostile caller's arguments to arena_put, arena_views and arena_tables: refused with an
    exception, never a write or read outside the buffers given (run in a child process: the
    build before this one crashed on most of them, a wild write or a pointer dereferenced)."""
    import os
    import subprocess
    import sys
    import deepcontact
    root = os.path.dirname(os.path.dirname(deepcontact.__file__))
    r = subprocess.run([sys.executable, "-c", ARENA_ABUSE], capture_output=True, text=True, timeout=120,
                       env=dict(os.environ, PYTHONPATH=root), cwd=root)
    assert r.returncode == 0, (r.returncode, r.stdout, r.stderr[-2000:])
    said = dict(line.rsplit(" ", 1) for line in r.stdout.splitlines())
    assert said == {"head past the arena": "ValueError", "reversed arena": "ValueError",
                    "beyond the reversed arena": "untouched", "a column no copy fits": "MemoryError",
                    "objects written": "ValueError", "objects read": "ValueError",
                    "head past the copy": "ValueError", "a shape past any size": "ValueError",
                    "a name that empties the columns": "TypeError"}, said
