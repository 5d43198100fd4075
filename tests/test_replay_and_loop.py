"""`dc validate --replay` and the project's solver driving Box2D (`dc simulate --solver pgs`)."""
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import dc
from deepcontact.errors import InputError
from deepcontact.scene.generators import generate
from deepcontact.scene.xml import read_scene
from deepcontact.simulate.build import build_world
from deepcontact.simulate.pgs_loop import PGSStepper
from deepcontact.solver.settings import SolveSettings
from deepcontact.step.reader import read_step

SCENES = Path(__file__).parent.parent / "datasets" / "scenes"
SMALL_PILE = ["pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps", "120"]


@pytest.mark.parametrize("iterations", ["8", "100"])
@pytest.mark.parametrize("scene", ["pile", "boxes-and-circles", "bouncing"])
def test_replay_is_exact(tmp_path, scene, iterations):
    args = SMALL_PILE if scene == "pile" else [str(SCENES / f"{scene}.xml"), "--steps", "120"]
    out = tmp_path / "run"
    assert dc("simulate", *args, "--iterations", iterations, "-q", "-o", str(out)).returncode == 0
    r = dc("validate", "--replay", "-q", str(out))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "largest difference 0: exact" in r.stdout


def test_replay_catches_a_changed_impulse(tmp_path):
    out = tmp_path / "run"
    assert dc("simulate", *SMALL_PILE, "-q", "-o", str(out)).returncode == 0
    step = sorted(out.glob("seed-*/step-*.xml"))[-1]
    text = step.read_text()
    i = text.index("<impulse n=\"") + len("<impulse n=\"")
    j = text.index("\"", i)
    step.write_text(text[:i] + repr(float(np.float32(text[i:j]) * np.float32(1.001))) + text[j:])
    r = dc("validate", "--replay", "-q", str(out))
    assert r.returncode == 1 and "NOT exact in 1 steps" in r.stdout and str(step) in r.stdout


def test_replay_refuses_what_it_cannot_check(tmp_path):
    r = dc("validate", "--replay", str(tmp_path))
    assert r.returncode == 1 and "no step files" in r.stderr
    out = tmp_path / "pgs"
    assert dc("simulate", *SMALL_PILE, "--solver", "pgs", "-q", "-o", str(out)).returncode == 0
    r = dc("validate", "--replay", str(out))
    assert r.returncode == 1 and "Box2D's own solver" in r.stderr


def run_both(scene, steps, settings):
    """Box2D's solver and ours side by side: per step, (max position difference, same impulses)."""
    ours, theirs = build_world(scene), build_world(scene)
    stepper = PGSStepper(ours, scene, settings, "builtin")
    out = []
    for _ in range(steps):
        _, c_theirs = theirs.step(scene.dt, scene.solver.velocity_iterations, scene.solver.position_iterations,
                                  record=True)
        c_ours = stepper.step().contacts
        same = (len(c_ours["manifold"]) == len(c_theirs["manifold"])
                and np.array_equal(c_ours["normal_impulse"], c_theirs["normal_impulse"])
                and np.array_equal(c_ours["tangent_impulse"], c_theirs["tangent_impulse"]))
        d = float(np.abs(ours.bodies()["position"] - theirs.bodies()["position"]).max())
        out.append((d, same, len(c_ours["manifold"])))
    return out


def test_exact_mode_in_the_loop_follows_box2d_up_to_the_divergence_point():
    # Until the first step with contacts the trajectories are identical. In that step our impulses
    # are Box2D's to the bit, but Box2D then applies them in one warm-start pass instead of eight
    # sweeps of increments, which rounds differently: positions part at float32 rounding level.
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    steps = run_both(scene, 150, SolveSettings(mode="exact", max_iterations=8, tolerance=0))
    first = next(k for k, (_, _, n) in enumerate(steps) if n)
    assert all(d == 0.0 and same for d, same, _ in steps[:first])
    assert steps[first][1]                          # same impulses, bit for bit
    assert steps[first][0] < 1e-6                   # positions part by rounding only
    # A stack stays together: after 300 steps the two are within 10 micrometres.
    stack = generate("stack", 0, dict(count=10))
    steps = run_both(stack, 300, SolveSettings(mode="exact", max_iterations=8, tolerance=0))
    assert max(d for d, _, _ in steps) < 1e-5


def test_exact_mode_hands_back_box2ds_impulses_with_their_signed_zeros():
    # (a frictionless stack: Box2D clamps each tangent impulse to [-0, 0] and writes -0 where it
    # pushed; the exact mode, which had left out the rows no friction needs, wrote +0)
    scene = generate("stack", 0, {"count": "5", "friction": "0"})
    k, positions = 8, scene.solver.position_iterations
    ours, theirs = build_world(scene), build_world(scene)
    for w in (ours, theirs):
        for _ in range(9):
            w.step(scene.dt, k, positions)
    _, want = theirs.step(scene.dt, k, positions, record=True)
    got = PGSStepper(ours, scene, SolveSettings(mode="exact", max_iterations=k, tolerance=0), "builtin").step().contacts
    assert np.signbit(want["tangent_impulse"]).any()
    for key in ("normal_impulse", "tangent_impulse"):
        assert np.array_equal(np.asarray(want[key], np.float64).view(np.uint64),
                              np.asarray(got[key], np.float64).view(np.uint64)), key


def test_the_residual_a_solve_stops_on_is_the_same_with_the_rows_no_friction_needs(tmp_path):
    # (the scale a residual is taken against read the tangent velocities of frictionless rows
    # posed all the same (prune=False): another residual of the same iterate, another stop)
    import deepcontact as dcl
    run = tmp_path / "run"
    assert dc("simulate", "confined", "--param", "count=100", "--steps", "40", "-q", "-o", run).returncode == 0
    for path in sorted(run.glob("seed-*/step-*.xml"))[5::5]:
        problem = dcl.StepProblem.from_step_file(path)
        for mode in ("float32", "float64"):
            pruned, posed = (dcl.solve(problem, mode=mode, tolerance=1e-6, stop_on="residual", max_iterations=500,
                                       prune=prune) for prune in (True, False))
            assert pruned.iterations == posed.iterations and pruned.residual == posed.residual, (path.name, mode)
            assert np.array_equal(pruned.normal_impulse, posed.normal_impulse), (path.name, mode)


STATIC_IN_MOTION = """<?xml version="1.0"?><scene name="slab" format="1"><world dt="0.016666668" steps="5"/>
<effects><gravity x="0" y="-9.81"/><friction coefficient="0.6"/></effects><bodies>
<body type="static" vx="0.5" omega="0.2"><polygon><vertex x="-4" y="-0.5"/><vertex x="4" y="-0.5"/>
<vertex x="4" y="0"/><vertex x="-4" y="0"/></polygon></body>
<body x="-2" y="0.5"><polygon density="1"><vertex x="-0.5" y="-0.5"/><vertex x="0.5" y="-0.5"/><vertex x="0.5" y="0.5"/>
<vertex x="-0.5" y="0.5"/></polygon></body>
<body x="2" y="0.5"><polygon density="1"><vertex x="-0.5" y="-0.5"/><vertex x="0.5" y="-0.5"/><vertex x="0.5" y="0.5"/>
<vertex x="-0.5" y="0.5"/></polygon></body>
</bodies></scene>
"""


def test_exact_mode_says_where_it_cannot_be_box2ds_own_answer(tmp_path):
    # (a static slab given a velocity under two boxes, two islands: Box2D moves the slab once for
    # each island before it poses the next; the loop poses both first, and its exact answers
    # differed from Box2D's by 1e-3 N s without a word)
    scene = tmp_path / "slab.xml"
    scene.write_text(STATIC_IN_MOTION)
    said = dc("simulate", scene, "--solver", "pgs", "--mode", "exact", "--max-iterations", "8", "-o", tmp_path / "a")
    assert said.returncode == 0 and said.stderr.count("is static with a velocity") == 1, said.stderr
    assert "slab.xml: body 0 is static with a velocity" in said.stderr and "not Box2D's" in said.stderr
    other = dc("simulate", scene, "--solver", "pgs", "--mode", "float32", "-o", tmp_path / "b")
    assert other.returncode == 0 and "static with a velocity" not in other.stderr, other.stderr


def test_simulate_with_pgs_records_iterations_and_residual(tmp_path):
    out = tmp_path / "run"
    r = dc("simulate", *SMALL_PILE, "--solver", "pgs", "--start", "zero", "--tolerance", "1e-4",
           "--max-iterations", "500", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert dc("validate", "-q", str(out)).returncode == 0
    iterations = []
    for path in sorted(out.glob("seed-*/step-*.xml"))[-20:]:
        header, _, c = read_step(path)
        text = path.read_text()
        i = text.index("<solve ")
        solve = text[i:text.index("/>", i)]
        n = int(solve.split('iterations="')[2].split('"')[0])
        res = float(solve.split('residual="')[1].split('"')[0])
        assert header["solver"]["name"] == "pgs" and 'start="zero"' in solve
        if len(c["manifold"]):
            assert 0 < n <= 500 and (res < 1e-4 or n == 500)
            assert not np.any(c["start_normal_impulse"])
        iterations.append(n)
    assert max(iterations) > 8


def test_pgs_options_need_the_pgs_solver_and_a_suitable_scene(tmp_path):
    r = dc("simulate", "pile", "--tolerance", "1e-3", "-o", str(tmp_path / "a"))
    assert r.returncode == 2 and "only applies with --solver pgs" in r.stderr   # options that do not go together
    r = dc("simulate", "bullet", "--solver", "pgs", "-o", str(tmp_path / "b"))
    assert r.returncode == 1 and "continuous collision" in r.stderr


@pytest.mark.parametrize("start,mode,w", [("builtin", "float64", 1.0), ("builtin", "float64", 1.7),
                                          ("zero", "float32", 1.0), ("builtin", "exact", 1.0),
                                          ("builtin", "float64", "auto")])
@pytest.mark.parametrize("scene", ["pile", "pyramid"])
def test_the_native_loop_step_matches_the_step_in_pieces(scene, start, mode, w):
    # One native call per step (pgs_step) against the same step taken in pieces through Python:
    # the same trajectory and the same recorded step, array for array, bit for bit.
    s = generate(scene, 0, dict(count=30, box=16.0, sigma=4.0) if scene == "pile" else dict(base=6))
    settings = SolveSettings(mode=mode, max_iterations=200 if mode != "exact" else 8,
                             tolerance=1e-4 if mode != "exact" else 0.0, relaxation=w)
    native, pieces = (PGSStepper(build_world(s), s, settings, start, native=n) for n in (True, False))
    assert native.native and not pieces.native
    solved = in_one_call = 0
    for _ in range(120):
        in_one_call += w != "auto" or not native.relaxation.wants_trial()
        a, b = native.step(), pieces.step()
        assert (a.solution is None) == (b.solution is None)
        if a.solution is not None:
            solved += 1
            assert a.solution.iterations == b.solution.iterations
            assert a.solution.relaxation == b.solution.relaxation
            assert np.array_equal(a.solution.normal_impulse, b.solution.normal_impulse)
        assert a.deepest == b.deepest
        for got, want in ((a.bodies, b.bodies), (a.contacts, b.contacts)):
            assert got.keys() == want.keys()
            for key in want:
                assert np.array_equal(got[key], want[key]), key
    assert solved > 20
    if scene == "pile":   # auto tunes in time here: most of its steps are one native call too
        assert in_one_call > 60
    assert np.array_equal(native.world.bodies()["position"], pieces.world.bodies()["position"])




def test_the_closed_loops_reference_is_computed_once_and_checked_before_use(tmp_path, monkeypatch):
    """The reference trajectory depends on no variant, yet every `dc evaluate --closed-loop` of a
    run stepped it again (92% of the command on the settled 1000-circle pile)."""
    from deepcontact.evaluate import closed_loop, reference_cache
    run = tmp_path / "run"
    assert dc("simulate", *SMALL_PILE[:-2], "--steps", "40", "--seeds", "0..1", "-q", "-o", run).returncode == 0
    args = ["evaluate", run, "--closed-loop", "--starts", "builtin", "--no-budgets", "--no-plots", "-q"]
    assert dc(*args, "-o", tmp_path / "first").returncode == 0
    kept = sorted(reference_cache.folder_for(run).iterdir())
    assert len(kept) == 2   # (one a simulation: its seed's scene)
    computed = []
    original = closed_loop.reference_trajectory
    monkeypatch.setattr(closed_loop, "reference_trajectory", lambda *a, **k: computed.append(a) or original(*a, **k))
    assert dc(*args, "-o", tmp_path / "again").returncode == 0
    assert computed == []   # (both read back)
    drift = {p.name: (p / "report.md").read_text().split("| builtin |")[1].split("|")[9:12]
             for p in (tmp_path / "first", tmp_path / "again")}
    assert drift["first"] == drift["again"], drift
    # another step count is another reference; a tampered or replaced file is not used
    assert dc(*args, "--steps", "30", "-o", tmp_path / "shorter").returncode == 0
    assert len(computed) == 2 and len(list(reference_cache.folder_for(run).iterdir())) == 4
    kept[0].write_bytes(kept[0].read_bytes()[:-40] + bytes(40))
    kept[1].unlink()
    kept[1].symlink_to(kept[0])
    assert dc(*args, "-o", tmp_path / "third").returncode == 0
    assert len(computed) == 4
    third = (tmp_path / "third" / "report.md").read_text().split("| builtin |")[1].split("|")[9:12]
    assert third == drift["first"]


def test_a_kept_reference_cut_short_or_behind_a_linked_folder_is_not_used(tmp_path, monkeypatch):
    # (a trajectory shorter than asked, its digest made again, had been read back; and the folder,
    # a link, was followed to write and read elsewhere)
    import io
    import json
    from deepcontact.evaluate import closed_loop, reference_cache
    run = tmp_path / "run"
    assert dc("simulate", *SMALL_PILE[:-2], "--steps", "40", "-q", "-o", run).returncode == 0
    args = ["evaluate", run, "--closed-loop", "--starts", "builtin", "--no-budgets", "--no-plots"]
    assert dc(*args, "-q", "-o", tmp_path / "first").returncode == 0
    [kept] = reference_cache.folder_for(run).iterdir()
    with np.load(kept, allow_pickle=False) as z:
        meta, arrays = json.loads(str(z["meta"])), {k: z[k] for k in z.files if k != "meta"}
    first = int(arrays["counts"][0])
    arrays.update(counts=arrays["counts"][:1], index=arrays["index"][:first], position=arrays["position"][:first],
                  **{k: arrays[k][:1] for k in ("energies", "iterations", "seconds", "residuals")})
    meta["digest"] = reference_cache._digest(arrays)
    buffer = io.BytesIO()
    np.savez(buffer, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    kept.write_bytes(buffer.getvalue())
    computed = []
    original = closed_loop.reference_trajectory
    monkeypatch.setattr(closed_loop, "reference_trajectory", lambda *a, **k: computed.append(a) or original(*a, **k))
    assert dc(*args, "-q", "-o", tmp_path / "again").returncode == 0
    assert len(computed) == 1
    drift = {p.name: (p / "report.md").read_text().split("| builtin |")[1].split("|")[9:12]
             for p in (tmp_path / "first", tmp_path / "again")}
    assert drift["first"] == drift["again"], drift
    elsewhere = tmp_path / "elsewhere"
    reference_cache.folder_for(run).rename(elsewhere)
    reference_cache.folder_for(run).symlink_to(elsewhere)
    before = {p.name: p.read_bytes() for p in elsewhere.iterdir()}
    done = dc(*args, "-o", tmp_path / "linked")
    assert done.returncode == 0 and len(computed) == 2
    assert "is a link, which dc never follows" in done.stderr, done.stderr
    assert {p.name: p.read_bytes() for p in elsewhere.iterdir()} == before


def in_lockstep(a, b, steps):
    """Two steppers stepped together `steps` times: each pair of their LoopSteps, whose solutions
    are there or not alike."""
    for _ in range(steps):
        x, y = a.step(), b.step()
        assert (x.solution is None) == (y.solution is None)
        yield x, y


def assert_same_answer(x, y):
    """Two solutions of one step: the same sweeps and the same impulses, bit for bit."""
    assert x.iterations == y.iterations
    assert np.array_equal(x.normal_impulse, y.normal_impulse)
    assert np.array_equal(x.tangent_impulse, y.tangent_impulse)


def a_start_of_ones_own(bodies, contacts, problem, builtin_n, builtin_t):
    # (a start no step carries: Box2D's warm start reshaped by the bodies and points it was asked on)
    lean = 0.5 + 0.25 * np.cos(np.arange(len(builtin_n)) + float(bodies["position"][:, 1].sum()))
    return builtin_n * lean, builtin_t * lean[::-1]


@pytest.mark.parametrize("mode,w,accelerate", [("float64", 1.0, "none"), ("exact", 1.0, "none"),
                                               ("float32", 1.3, "nncg"), ("float64", 1.0, "lagged")])
@pytest.mark.parametrize("scene", ["pile", "pyramid"])
def test_a_start_made_between_the_native_halves_is_the_step_in_pieces(scene, mode, w, accelerate):
    # A start made in Python (the closed loop's) steps on pgs_pose and pgs_finish: the same
    # trajectory, bit for bit, as the step in pieces, which poses it a second time in Python
    s = generate(scene, 0, dict(count=30, box=16.0, sigma=4.0) if scene == "pile" else dict(base=6))
    global_method = accelerate == "lagged"
    settings = SolveSettings(mode=mode, max_iterations=200 if mode != "exact" else 8,
                             tolerance=1e-4 if mode != "exact" else 0.0, relaxation=w, accelerate=accelerate,
                             **(dict(stop_on="residual") if global_method else {}))
    posed, pieces = (PGSStepper(build_world(s), s, settings, "builtin", start_fn=a_start_of_ones_own, record=False,
                                native=n, residual=True) for n in (True, False))
    assert posed.posed and not pieces.posed
    solved = 0
    for a, b in in_lockstep(posed, pieces, 100):
        if a.solution is not None:
            solved += 1
            assert_same_answer(a.solution, b.solution)
            assert a.solution.residual == b.solution.residual or np.isnan(a.solution.residual) == np.isnan(b.solution.residual)
        assert a.deepest == b.deepest and a.dt_ratio == b.dt_ratio
        for key in ("position", "angle", "velocity", "omega"):
            assert np.array_equal(posed.world.bodies()[key], pieces.world.bodies()[key]), key
    assert solved > 20


def test_the_native_halves_refuse_a_world_changed_between_them():
    from deepcontact._box2d import pgs_finish, pgs_pose
    s = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    stepper = PGSStepper(build_world(s), s, SolveSettings(), "builtin", start_fn=a_start_of_ones_own, record=False)
    for _ in range(40):
        stepper.step()
    world, settings = stepper.world, stepper.step_settings
    points = pgs_pose(world, settings)
    assert points > 0
    with pytest.raises(ValueError, match="impulses a row"):
        pgs_finish(world, settings, np.zeros(points + 1), np.zeros(points + 1))
    world.set_body_state([0], [[0.0, 3.0]], [0.0], [[0.0, 0.0]], [0.0])
    with pytest.raises(ValueError, match="changed since pgs_pose"):
        pgs_finish(world, settings, np.zeros(points), np.zeros(points))
    pgs_pose(world, settings)
    settings.solve.mode = "float32"
    with pytest.raises(ValueError, match="another precision"):
        pgs_finish(world, settings, np.zeros(points), np.zeros(points))


def trajectories(steppers, steps):
    """Each stepper's steps: per step its answer, deepest point and the bodies after it."""
    out = [[] for _ in steppers]
    for _ in range(steps):
        for stepper, seen in zip(steppers, out):
            done = stepper.step()
            b = stepper.world.bodies()
            seen.append((None if done.solution is None else (done.solution.normal_impulse.tolist(),
                                                              done.solution.tangent_impulse.tolist(),
                                                              done.solution.iterations, done.solution.relaxation),
                         done.deepest, done.dt_ratio, *(b[k].tobytes() for k in ("position", "angle", "velocity", "omega"))))
    return out


def a_start_that_changes_what_it_is_given(bodies, contacts, problem, builtin_n, builtin_t):
    # (what it changes is its own: neither path solves, steps or measures it)
    start = a_start_of_ones_own(bodies, contacts, problem, builtin_n, builtin_t)
    problem.contacts["friction"][:] = 0.0
    problem.bodies["velocity"][:] = 0.0
    contacts["separation"][:] = -5.0
    bodies["position"][:] = 0.0
    builtin_n *= 0.0
    return [float(x) for x in start[0]], start[1]


@pytest.mark.parametrize("warm", [True, False])
def test_a_start_that_changes_what_it_is_given_steps_alike_between_the_halves_and_in_pieces(warm):
    # The step between the native halves reads nothing back from Python; the step in pieces
    # (a recorded step, a plug-in method) solved the problem the start was handed, and measured
    # its deepest point from the contacts: a start that changed them stepped another trajectory
    s = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    s = replace(s, solver=replace(s.solver, warm_starting=warm))
    settings = SolveSettings(max_iterations=200, tolerance=1e-4)
    steppers = [PGSStepper(build_world(s), s, settings, "builtin", start_fn=f, record=False, native=n, residual=True)
                for f in (a_start_that_changes_what_it_is_given, a_start_of_ones_own) for n in (True, False)]
    assert [p.posed for p in steppers] == [True, False, True, False]
    changing_posed, changing_pieces, posed, pieces = trajectories(steppers, 60)
    assert changing_pieces == changing_posed == posed == pieces
    assert sum(step[0] is not None for step in posed) > 20


@pytest.mark.parametrize("made", [lambda n: n.astype(complex) + 1j, lambda n: n.astype(object), lambda n: n.astype(str),
                                  lambda n: n > 0, lambda n: n[:, None], lambda n: np.append(n, 0.0), lambda n: 1.0],
                         ids=["complex", "objects", "text", "bool", "2-d", "one-too-many", "a-number"])
def test_a_start_of_another_form_is_refused_alike_between_the_halves_and_in_pieces(made):
    # pgs_finish converted whatever numpy could cast (text, objects, booleans) and named itself
    # for a wrong length; the step in pieces refuses them, naming the start, as solve does
    s = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))

    def start(bodies, contacts, problem, builtin_n, builtin_t):
        return made(builtin_n), builtin_t
    said = []
    for native in (True, False):
        stepper = PGSStepper(build_world(s), s, SolveSettings(), "builtin", start_fn=start, record=False, native=native)
        with pytest.raises(InputError, match="argument 'start_normal' must be one value per contact point") as e:
            for _ in range(60):
                stepper.step()
        said.append(str(e.value))
    assert said[0] == said[1]


def test_a_start_of_none_is_the_problems_own_between_the_halves_and_in_pieces():
    s = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    steppers = [PGSStepper(build_world(s), s, SolveSettings(max_iterations=50, tolerance=1e-4), "builtin",
                           start_fn=f, record=False, native=n, residual=True)
                for f in (lambda *a: (None, None), lambda b, c, p, n, t: (n, t)) for n in (True, False)]
    none_posed, none_pieces, builtin_posed, builtin_pieces = trajectories(steppers, 60)
    assert none_posed == none_pieces == builtin_posed == builtin_pieces


def test_a_start_not_a_number_steps_alike_between_the_halves_and_in_pieces():
    # Exact mode uses a start as given: a NaN answer, applied, leaves the static ground (in every
    # island) NaN, and Box2D poses a later island's contacts from it. The native island solve
    # posed them all first: bodies in later islands kept finite velocities Box2D's Step made NaN.
    # On the next step the world is not finite: both refuse it as solve does (pgs_finish stepped on)
    s = read_scene(SCENES / "bouncing.xml")

    def not_a_number(bodies, contacts, problem, builtin_n, builtin_t):
        return np.where(np.arange(len(builtin_n)) == 0, np.nan, builtin_n), np.where(
            np.arange(len(builtin_t)) == len(builtin_t) - 1, np.inf, builtin_t)
    steppers = [PGSStepper(build_world(s), s, SolveSettings(mode="exact"), "builtin", start_fn=not_a_number,
                           record=False, native=n, residual=True) for n in (True, False)]
    for _ in range(80):
        said = []
        for stepper in steppers:
            try:
                stepper.step()
                said.append(None)
            except InputError as e:
                said.append(str(e))
        assert said[0] == said[1]
        if said[0] is not None:
            break
        for key in ("position", "angle", "velocity", "omega"):
            assert np.array_equal(*(p.world.bodies()[key] for p in steppers), equal_nan=True), key
    assert said[0] is not None and "holds a value that is not finite" in said[0]


def test_a_relaxation_of_none_stands_as_one_on_every_path():
    # SolveSettings(relaxation=None) is a built-in method's w of 1 (solve takes it so): the native
    # step and the step between the halves handed None to the native options (a TypeError)
    s = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    steppers = [PGSStepper(build_world(s), s, SolveSettings(relaxation=w, max_iterations=50, tolerance=1e-4),
                           "builtin", start_fn=f, record=False, native=n, residual=True)
                for w in (None, 1.0) for f in (None, a_start_of_ones_own) for n in (True, False)]
    native, pieces, posed, own_pieces, *ones = trajectories(steppers, 60)
    assert native == pieces == ones[0] == ones[1] and posed == own_pieces == ones[2] == ones[3]


def box2d_then_loop(scene, settings, native, steps=80):
    """Two copies of the scene stepped `steps` times by Box2D at 8 iterations; then one more step of
    the first by the loop and of the second by Box2D: (the loop's world, its step, Box2D's contacts)."""
    ours, theirs = build_world(scene), build_world(scene)
    for world in (ours, theirs):
        for _ in range(steps):
            world.step(scene.dt, 8, scene.solver.position_iterations)
    _, want = theirs.step(scene.dt, 8, scene.solver.position_iterations, record=True)
    return ours, PGSStepper(ours, scene, settings, "builtin", native=native).step(), want


@pytest.mark.parametrize("native", [True, False])
def test_a_world_box2d_stepped_goes_on_in_the_loop_from_what_box2d_carried(native):
    # The loop's first step of a world Box2D has been stepping carries Box2D's impulses, times
    # the dtRatio Box2D's own next step would use: in Box2D's exact arithmetic at its 8 sweeps that
    # step's impulses are Box2D's own next step's, bit for bit (from zero they were not).
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    settings = SolveSettings(mode="exact", max_iterations=8, tolerance=0)
    ours, done, want = box2d_then_loop(scene, settings, native)
    assert len(want["normal_impulse"]) > 10 and np.any(done.contacts["start_normal_impulse"])
    assert done.dt_ratio == float(np.float32(np.float32(1 / np.float32(scene.dt)) * np.float32(scene.dt)))
    assert np.array_equal(done.contacts["normal_impulse"], want["normal_impulse"])
    assert np.array_equal(done.contacts["tangent_impulse"], want["tangent_impulse"])
    # a world that no one stepped carries nothing into its first step, as Box2D's own first step
    fresh = PGSStepper(build_world(scene), scene, settings, "builtin", native=native).step()
    assert fresh.dt_ratio == 0.0


@pytest.mark.parametrize("mode, w, accelerate", [("exact", 1.0, "none"), ("float64", 1.0, "none"),
                                                 ("float32", 1.7, "none"), ("float64", 1.3, "nncg")])
def test_an_unrecorded_step_at_fixed_sweeps_skips_only_its_residual(mode, w, accelerate):
    # The residual after the sweeps (and its scale before them) is measured only where something
    # reads it: an unrecorded step at a fixed sweep count reports none, and every iterate, the
    # guard's decisions included, is the same as the step that reports it.
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    settings = SolveSettings(mode=mode, max_iterations=12, tolerance=0, relaxation=w, accelerate=accelerate)
    bare, told = (PGSStepper(build_world(scene), scene, settings, "builtin", record=False, residual=r)
                  for r in (None, True))
    assert not bare.residual and told.residual
    solved = 0
    for a, b in in_lockstep(bare, told, 100):
        if a.solution is not None:
            solved += 1
            assert np.isnan(a.solution.residual) and np.isfinite(b.solution.residual)
            assert a.solution.relaxation_fallback == b.solution.relaxation_fallback
            assert_same_answer(a.solution, b.solution)
    assert solved > 50
    assert np.array_equal(bare.world.bodies()["position"], told.world.bodies()["position"])
    # recorded, or solved to a tolerance, a step states its residual unasked
    recorded = PGSStepper(build_world(scene), scene, settings, "builtin")
    to_tolerance = PGSStepper(build_world(scene), scene, settings.but(tolerance=1e-3, max_iterations=50), "builtin",
                              record=False)
    assert recorded.residual and to_tolerance.residual


@pytest.mark.parametrize("mode, w", [("float32", 1.9), ("float64", 1.95)])
def test_the_guard_decides_the_same_without_the_residual(mode, w):
    # Where the guard fires on step after step (a pyramid, NNCG at a high w), an unrecorded step at
    # a fixed sweep count takes the same iterates and the same fallbacks as one stating its residual.
    scene = generate("pyramid", 0, dict(base=8))
    settings = SolveSettings(mode=mode, max_iterations=64, tolerance=0, relaxation=w, accelerate="nncg")
    bare, told = (PGSStepper(build_world(scene), scene, settings, "builtin", record=False, residual=r)
                  for r in (None, True))
    fallbacks = 0
    for _ in range(60):
        a, b = bare.step(), told.step()
        if b.solution is not None:
            fallbacks += b.solution.relaxation_fallback > 0
            assert np.isnan(a.solution.residual) and a.solution.relaxation_fallback == b.solution.relaxation_fallback
            assert np.array_equal(a.solution.normal_impulse, b.solution.normal_impulse)
    assert fallbacks >= 5
    assert np.array_equal(bare.world.bodies()["position"], told.world.bodies()["position"])


@pytest.mark.parametrize("native", [True, False])
def test_the_loop_honours_a_world_without_warm_starting(native):
    # Off, Box2D's solver starts every step from zero, and it applies written impulses only as its
    # warm start: the loop carried the impulses in and its answers were dropped (the pile fell
    # through the ground). Now each step starts from zero and moves the bodies: from a world Box2D
    # stepped, in exact mode at its 8 sweeps, the step's impulses are Box2D's own next step's.
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    scene.solver.warm_starting = False
    settings = SolveSettings(mode="exact", max_iterations=8, tolerance=0)
    ours, done, want = box2d_then_loop(scene, settings, native)
    assert len(want["normal_impulse"]) > 10 and not np.any(done.contacts["start_normal_impulse"])
    assert np.array_equal(done.contacts["normal_impulse"], want["normal_impulse"])
    assert np.array_equal(done.contacts["tangent_impulse"], want["tangent_impulse"])
    assert not ours.warm_starting   # (the world's own switch as it was)
    stepper = PGSStepper(build_world(scene), scene, settings, "builtin", native=native)
    for _ in range(150):
        stepper.step()
    bodies = stepper.world.bodies()
    assert bodies["position"][bodies["type"] == 2, 1].min() > 0.9   # radius 1, on the ground at 0


@pytest.mark.parametrize("native", [True, False])
def test_a_loop_step_after_box2d_stepped_the_world_at_another_dt_carries_box2ds_ratio(native):
    # The loop's steps leave dtRatio exactly 1; a step Box2D's own solver took in between, at
    # another dt, leaves what Box2D's next step would use (here 2): the loop's next step carries
    # that (it carried 1), and in exact mode at 8 sweeps its impulses are Box2D's own, bit for bit.
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    settings = SolveSettings(mode="exact", max_iterations=8, tolerance=0)
    ours, theirs = (PGSStepper(build_world(scene), scene, settings, "builtin", native=native) for _ in range(2))
    for _ in range(90):
        ours.step(), theirs.step()
    for stepper in (ours, theirs):
        stepper.world.step(scene.dt / 2, 8, scene.solver.position_iterations)
    _, want = theirs.world.step(scene.dt, 8, scene.solver.position_iterations, record=True)
    done = ours.step()
    assert done.dt_ratio == theirs.world.last_dt_ratio > 1.99
    assert len(want["normal_impulse"]) > 10
    assert np.array_equal(done.contacts["normal_impulse"], want["normal_impulse"])
    assert np.array_equal(done.contacts["tangent_impulse"], want["tangent_impulse"])
    assert ours.step().dt_ratio == 1.0   # (the loop's own steps again: exactly 1)


def test_a_step_in_pieces_after_bodies_are_placed_records_one_start_a_contact_row():
    """Bodies turned in place (set_body_state) between steps: Box2D's Step of the step in pieces
    recorded contact rows the collided ones did not have, and the step's start, one a collided row,
    was recorded beside them, shorter than the contacts. Both paths now record no start there."""
    from deepcontact.scene.model import Body, Circle, Edge, Effects, Polygon, Scene, Solver, f32

    def box(hx, hy, cx=0.0, cy=0.0):
        return Polygon(((cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)), density=1.0)
    rng = np.random.default_rng(3)
    bodies = [Body(type="static", shapes=[Edge(-30, 0, 30, 0)]), Body(type="static", x=-8, y=0.5, angle=-0.0, shapes=[box(0.5, 2)]),
              Body(type="static", x=8, y=0.5, shapes=[box(0.5, 2)]),
              Body(type="kinematic", y=0.6, omega=0.7, vx=0.2, angle=-0.0, shapes=[box(2, 0.2, cx=0.3, cy=0.1)])]
    for i in range(40):
        x, y = rng.uniform(-7, 7), rng.uniform(1, 14)
        angle = float(rng.choice([-0.0, 0.0, rng.uniform(-3, 3), 1e5 * rng.uniform(-1, 1)]))
        shapes = [[Circle(0.4, density=1)], [box(0.4, 0.25, cx=0.1, cy=-0.05)],
                  [box(0.3, 0.3), Circle(0.25, x=0.5, y=0.0, density=2), box(0.1, 0.4, cx=-0.4)],
                  [Circle(0.3, x=0.2, y=0.1, density=1), Circle(0.2, x=-0.3, density=1)]][i % 4]
        bodies.append(Body(x=float(f32(x)), y=float(f32(y)), angle=angle, omega=float(rng.uniform(-3, 3)), shapes=shapes))
    scene = Scene(name="turned", dt=f32(1 / 60), steps=200, solver=Solver(position_iterations=3), bodies=bodies,
                  effects=Effects(gravity=(0.0, -9.81), friction=0.5, restitution=0.2))
    for native in (False, True):
        world = build_world(scene)
        stepper = PGSStepper(world, scene, SolveSettings(mode="float64", max_iterations=30), "builtin", native=native)
        for k in range(4):
            if k == 3:
                b = world.bodies()
                turned = np.flatnonzero(b["type"] == 2)[::3]
                world.set_body_state(b["index"][turned], b["position"].reshape(-1, 2)[turned],
                                     np.full(len(turned), -0.0, np.float32), b["velocity"].reshape(-1, 2)[turned],
                                     b["omega"][turned])
            step = stepper.step()
        rows = {name: len(step.contacts[name]) for name in ("normal_impulse", "start_normal_impulse",
                                                              "start_tangent_impulse")}
        assert len(set(rows.values())) == 1, (native, rows)
