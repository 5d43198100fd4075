"""What every benchmark script starts with: its options, and a line saying how its times are taken."""
import argparse
import subprocess
import sys
import time

from deepcontact.protocol import current, protocol_line

DC = [sys.executable, "-m", "deepcontact.cli.main"]   # dc, as this interpreter runs it


def arguments(doc, **defaults):
    """The script's options (--name for each keyword, typed by its default), parsed, after the
    protocol line (threads, -j, versions, CPU, load, command) is printed."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name, default in defaults.items():
        ap.add_argument("--" + name.replace("_", "-"), type=type(default), default=default)
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    return args


def timed(args):
    """(wall seconds, peak resident MB) of one whole command, which must succeed. The peak is
    measured by GNU time around the command: a child forked from this (large) process would count
    this process's memory at the fork as its own."""
    t = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-f", "%M", *DC, *args], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        sys.exit(f"failed: dc {' '.join(args)}\n{proc.stderr[-2000:]}")
    return wall, int(proc.stderr.strip().splitlines()[-1]) / 1024
