"""How much does recording cost? `dc simulate` on the thesis pile (100 circles, 600 steps,
XML on) as a whole process, start-up included, next to baselines measured in the same run:

  bare       Box2D stepping only, no recording (in-process)
  record     stepping + moving each step to numpy (in-process)
  dc         `dc simulate pile` as a user runs it (a fresh process, files written)
  thesis-xml the thesis pipeline's writing approach on the same arrays: a Python-side
             export into ElementTree, pretty-printed with minidom, as the thesis code did, on a sample of
             steps (in-process)

Usage: python benchmarks/bench_simulate.py [--repeats N] [--json FILE]
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import xml.dom.minidom
import xml.etree.ElementTree as ET

from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.protocol import current, protocol_line


def best_of(repeats, fn):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times), statistics.median(times)


def bare(scene, record):
    world = build_world(scene)
    for _ in range(scene.steps):
        world.step(scene.dt, 8, 3, record=record)


def whole_process(tmp):
    out = os.path.join(tmp, "run")
    shutil.rmtree(out, ignore_errors=True)
    # The installed console script next to this interpreter (not a version-manager shim,
    # which adds its own start-up time on some machines).
    exe = os.path.join(os.path.dirname(sys.executable), "dc")
    cmd = [exe] if os.path.exists(exe) else [sys.executable, "-m", "deepcontact.cli.main"]
    # Bytecode cached as on a user's machine, even where PYTHONDONTWRITEBYTECODE is set.
    env = dict(os.environ, PYTHONPYCACHEPREFIX=os.path.join(tmp, "pycache"))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    subprocess.run(cmd + ["simulate", "pile", "-q", "-o", out], check=True, env=env)


def thesis_style_xml(bodies, contacts):
    """Attribute-by-attribute Python export, ElementTree, minidom pretty-printing."""
    root = ET.Element("state")
    for i in range(len(bodies["index"])):
        b = ET.SubElement(root, "body", index=str(int(bodies["index"][i])),
                          type="free" if bodies["type"][i] == 2 else "fixed")
        ET.SubElement(b, "mass", value=str(float(bodies["mass"][i])))
        ET.SubElement(b, "position", x=str(float(bodies["position"][i, 0])), y=str(float(bodies["position"][i, 1])))
        ET.SubElement(b, "velocity", x=str(float(bodies["velocity"][i, 0])), y=str(float(bodies["velocity"][i, 1])))
        ET.SubElement(b, "orientation", theta=str(float(bodies["angle"][i])))
        ET.SubElement(b, "inertia", value=str(float(bodies["inertia"][i])))
        ET.SubElement(b, "spin", omega=str(float(bodies["omega"][i])))
        ET.SubElement(b, "shape", value="circle")
    for k in range(len(contacts["manifold"])):
        c = ET.SubElement(root, "contact", index=str(k), master=str(int(contacts["body_a"][k])),
                          slave=str(int(contacts["body_b"][k])))
        ET.SubElement(c, "position", x=str(float(contacts["position"][k, 0])), y=str(float(contacts["position"][k, 1])))
        ET.SubElement(c, "normal", normal=f"b2Vec2({float(contacts['normal'][k, 0])},{float(contacts['normal'][k, 1])})")
        ET.SubElement(c, "impulse", n=str(float(contacts["normal_impulse"][k])),
                      t=str(float(contacts["tangent_impulse"][k])))
    return xml.dom.minidom.parseString(ET.tostring(root)).toprettyxml(indent="  ").encode()


def thesis_xml(scene, tmp, sample=60):
    world = build_world(scene)
    steps = []
    for k in range(scene.steps):
        b, c = world.step(scene.dt, 8, 3, record=True)
        if k % (scene.steps // sample) == 0:
            steps.append((b, c))
    t = time.perf_counter()
    for k, (b, c) in enumerate(steps):
        with open(os.path.join(tmp, f"thesis-{k}.xml"), "wb") as f:
            f.write(thesis_style_xml(b, c))
    return (time.perf_counter() - t) / len(steps)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json")
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    scene = generate("pile", 0)
    n = scene.steps
    with tempfile.TemporaryDirectory() as tmp:
        whole_process(tmp)   # warm the page cache and the interpreter's files
        rows = {
            "bare": best_of(args.repeats, lambda: bare(scene, False)),
            "record": best_of(args.repeats, lambda: bare(scene, True)),
            "dc": best_of(args.repeats, lambda: whole_process(tmp)),
        }
        thesis = thesis_xml(scene, tmp)
    per_step = {k: (v[0] / n * 1e3, v[1] / n * 1e3) for k, v in rows.items()}
    per_step["thesis-xml"] = (thesis * 1e3, thesis * 1e3)
    print(f"pile: 100 circles, {n} steps, 8 velocity iterations; best and median of {args.repeats}, "
          f"ms per step")
    print(f"{'':12s}{'best':>8s}{'median':>8s}{'x bare':>9s}")
    for name, (best, med) in per_step.items():
        print(f"{name:12s}{best:8.3f}{med:8.3f}{best / per_step['bare'][0]:9.1f}")
    dc_ms = per_step["dc"][0]
    print(f"dc simulate: {dc_ms:.3f} ms/step with XML, start-up included (target <= 1 ms); "
          f"thesis-style XML writing alone is {per_step['thesis-xml'][0] / dc_ms:.0f}x slower")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"ms_per_step": per_step, "steps": n}, f, indent=2)


if __name__ == "__main__":
    main()
