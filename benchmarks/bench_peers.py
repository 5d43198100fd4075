"""Does stepping pymunk and MuJoCo through the project cost what stepping them bare costs, and
what does recording their steps add?

For each engine, on a pile (the 1000-circle pile by default: seed 9, its settled second half), in
the same run, one thread, best of --repeats (the two ways interleaved), the same model both ways:
  bare      the engine's own step called in a loop: pymunk's `space.step(dt)`, MuJoCo's
            `mj_step(model, data)` on the space and model the project built from the scene
  project   the same world stepped through the project's loop (simulate.stepping.steps, the
            engine's step function without recording): what the studies time
  recording the project's loop recording every step (the arrays a step file holds), as
            `dc simulate` steps (without rendering and writing the XML)
Box2D 2.4.1 at 8 iterations is stepped beside them as the baseline of the ratios. The goal: the
project's time within 1.2x of the bare one.

With --orders, MuJoCo's step alone (mj_step) on the same settled pile under each order of its
bodies (`--set order=`: columns, rows, the scene's): its sparse factor does not reorder.

Usage: python benchmarks/bench_peers.py [--repeats N] [--count N] [--steps N] [--orders]
"""
import argparse
import time

from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.simulate.engines import engine_named
from deepcontact.simulate.stepping import steps


def settled(scene, engine, first):
    """The engine's world stepped `first` steps (to the settled part of the run)."""
    world = engine.build(scene)
    for _ in steps(world, scene, engine.stepper(world, scene, record=False), count=first):
        pass
    return world


def bare_step(name, world):
    if name == "pymunk":
        space, dt = world.space, world.dt
        return lambda: space.step(dt)
    if name == "mujoco":
        import mujoco
        model, data = world.model, world.data
        return lambda: mujoco.mj_step(model, data)
    return None


def timed(step, n):
    t = time.perf_counter()
    for _ in range(n):
        step()
    return (time.perf_counter() - t) / n


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--count", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=100, help="steps timed, from step 400 (the settled pile)")
    ap.add_argument("--orders", action="store_true", help="MuJoCo's step under each order of its bodies")
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")
    if args.orders:
        return orders(args)
    params = {"count": args.count, "box": 95.0, "sigma": 19.0} if args.count > 100 else {"count": args.count}
    scene = generate("pile", 9, {**params, "steps": 400 + args.steps * (2 * args.repeats + 2)})
    print(f"pile of {args.count} circles, seed 9, {args.steps} steps from step 400, best of {args.repeats}\n")
    print("| engine | bare ms / step | through the project | project / bare | recording | x Box2D 2.4.1 (8 it.) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    base = None
    for name in ("box2d", "pymunk", "mujoco"):
        engine = engine_named(name)
        world = settled(scene, engine, 400)
        loop = engine.stepper(world, scene, record=False)
        through = iter(steps(world, scene, loop, count=10 ** 9))
        raw = bare_step(name, world)
        project, bare = float("inf"), float("inf")
        for _ in range(args.repeats):   # (interleaved: a change of load falls on both)
            project = min(project, timed(lambda: next(through), args.steps))
            if raw is not None:
                bare = min(bare, timed(raw, args.steps))
        recording = iter(steps(world, scene, engine.stepper(world, scene, record=True), count=10 ** 9))
        record = min(timed(lambda: next(recording), args.steps) for _ in range(args.repeats))
        base = project if base is None else base
        label = engine.label if engine.version() in engine.label else f"{engine.label} {engine.version()}"
        bare_ms, ratio = (f"{1e3 * bare:.3f}", f"{project / bare:.2f}x") if raw is not None else ("-", "-")
        print(f"| {label} | {bare_ms} | {1e3 * project:.3f} | {ratio} | {1e3 * record:.3f} | {project / base:.1f}x |",
              flush=True)


def orders(args):
    import mujoco
    params = {"count": args.count, "box": 95.0, "sigma": 19.0} if args.count > 100 else {"count": args.count}
    scene = generate("pile", 9, {**params, "steps": 1000})
    print(f"MuJoCo's mj_step on the pile of {args.count} circles, seed 9, after 400 steps; {args.steps} steps, "
          f"best of {args.repeats}\n")
    print("| order | ms / step | iterations (largest island) |")
    print("| --- | ---: | ---: |")
    for order in ("columns", "rows", "scene"):
        world = settled(scene, engine_named("mujoco", {"order": order}), 400)
        step = bare_step("mujoco", world)
        ms = 1e3 * min(timed(step, args.steps) for _ in range(args.repeats))
        print(f"| {order} | {ms:.1f} | {int(world.data.solver_niter[0])} |", flush=True)


if __name__ == "__main__":
    main()
