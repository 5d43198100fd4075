"""The contest's floor: contestants fenced and charged as programming-contest judges fence and
charge submissions.

- `wire`: the requests and answers between the judge and a contestant, packed and checked in one place;
- `sandbox`: one contestant's fence (bubblewrap namespaces, seccomp, a control group, limits);
- `guest`: the contestant's side, a fresh interpreter in its sandbox;
- `broker`: contestants of a fenced job (a study), started by the judge's process on its behalf;
- `client`: the judge's side, one charged call (wall time or CPU, the larger) with its deadline;
- `verdict`: one rule that names a winner, or says there is none, for replay and loop alike.

evaluate/ and the studies consume it; it imports nothing above the warm starts.
"""
from .client import Contestant, RemoteMethod, deadline_for, describe, start_all
from .broker import describe_fences, fences, missing_fences

__all__ = ["Contestant", "RemoteMethod", "deadline_for", "describe", "describe_fences", "fences", "missing_fences",
           "start_all"]
