"""The contest's floor: contestants fenced and charged as programming-contest judges fence and
charge submissions.

- `wire`: the requests and answers between the judge and a contestant, packed and checked in one place;
- `fence`: the one record of a sandbox's rules and its profiles (contestant, engine, job, ...);
- `sandbox`: one fence around one command (bubblewrap namespaces, seccomp, a control group, limits);
- `relay`: a sandbox's output and error, relayed by dc under its name, bounded;
- `guest`: the contestant's side, a fresh interpreter in its sandbox;
- `broker`: contestants of a fenced job (a study), started by the judge's process on its behalf;
- `client`: the judge's side, one charged call (wall time or CPU, the larger) with its deadline;
- `charge`: a loop step's calls charged, less the null contestant's least round trip over the run;
- `keyed`: contact keys matched as arrays (the loop's persisted points and previous impulses);
- `arena`: the loop's step context in shared memory, mapped read-only by its contestants;
- `verdict`: one rule that names a winner, or says there is none, for replay and loop alike.

evaluate/ and the studies consume it; it imports nothing above the warm starts.

Its names are loaded on first use: every contestant's fresh interpreter imports `guest`, to
which the judge's side (client, broker, sandbox) would add 17 ms of about 100 (-X importtime).
"""
import importlib

_NAMES = {"client": ("Contestant", "RemoteMethod", "deadline_for", "describe", "start_all"),
          "broker": ("describe_fences", "fences", "missing_fences")}
__all__ = sorted(name for names in _NAMES.values() for name in names)


def __getattr__(name):
    for module, names in _NAMES.items():
        if name in names:
            return getattr(importlib.import_module(f"{__name__}.{module}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
