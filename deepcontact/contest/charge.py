"""What a step of a loop is charged for the calls it made to a contestant (the closed loop's rule).

A step's wall time holds its contestant's calls and the null contestant's round trips of the same
requests. Both are taken out of it, and each call put back at its charge: the larger of its wall
time less the null's least round trip of that kind of request over the whole run, and the CPU its
sandbox used in the call (Contestant.call measures both) less the null's least for that kind of
request; never below zero. The floors are the null's least over the run, of the variant's own
requests (an oracle's carry the reference), so that a contestant that slows the null (work left
running in its sandbox) cannot enlarge what is subtracted.

The CPU its group was charged that no call can have used (`split_cpu`: Contestant.outside, summed
in its outside_s) is charged too, spread evenly over the steps that asked it (`unasked`; replay's:
replay.spread_unasked): what it
used between calls, unasked (work left running), and what a call's reads show beyond what the
threads it is granted could run in that call's wall time (run before it and accounted late, or run
on threads it was not granted). The kernel
accounts a process running on another core into its control group only at a scheduler tick (every
few milliseconds), so that work reaches the judge's reads in lumps that land on a few steps, which
a median step would miss; which step it served no one can say, and evenly it raises every step's
time alike. Less the null contestant's mean of the same, as many times: every guest's send and
return to its line, after the judge's read, a few microseconds a call. A call's own parallel work
on the threads it is granted (`dc evaluate --threads`) stays that call's, so a start's steps keep
their shape; a lump up to that bound that the kernel accounts during a call stays there too.
"""
import math

import numpy as np


class NullFloors:
    """The null contestant's least round trip (wall, CPU) of each kind of request over a run so
    far: the floors call_charge takes, which no contestant can raise by slowing the null."""

    def __init__(self):
        self.least = {}   # kind of request -> (least wall, least CPU)

    def seen(self, kind, null):
        """Takes the null's round trip `null` ((wall, CPU): its `last`) of a `kind` request; the floor now."""
        wall, cpu = self.least.get(kind, (math.inf, math.inf))
        self.least[kind] = (min(wall, null[0]), min(cpu, null[1]))
        return self.least[kind]


class StepCharges:
    """One variant's calls in a loop, step by step: `record` after each call (with the null's
    round trip of the same request), `step_done` after each step; at the end of the run, with the
    floors its null round trips set (`nulls`: the least of each kind), `charged`, `uncharged` and
    `unasked` per step."""

    def __init__(self):
        self.steps, self.calls, self.within = [], [], 0.0
        self.floors = NullFloors()
        self.nulls = self.floors.least   # kind of request -> (least wall, least CPU) of the null's round trips

    def record(self, kind, contestant, null):
        """After `contestant` and `null` answered the same request of this kind (their `last`)."""
        wall, cpu = in_call(contestant)
        self.within += wall + null.last[0]
        self.calls.append((kind, wall, cpu))
        self.floors.seen(kind, in_call(null))

    def step_done(self):
        """Closes the step (a step that asked nothing: no calls, charged nothing)."""
        self.steps.append((self.within, self.calls))
        self.within, self.calls = 0.0, []

    def charged(self, kinds=None):
        """Seconds charged per step for its calls (of `kinds`, default all), once the run is over."""
        return np.array([sum(call_charge(wall, cpu, self.nulls[kind]) for kind, wall, cpu in calls
                             if kinds is None or kind in kinds) for _, calls in self.steps], np.float64)

    def unasked(self, pool):
        """Seconds charged per step for `pool` seconds of CPU that no call can have used
        (unasked_pool), evenly over the steps that asked it something (one that asked nothing is
        charged nothing)."""
        asked = np.array([bool(calls) for _, calls in self.steps], bool)
        return np.where(asked, pool / max(int(asked.sum()), 1), 0.0)

    def uncharged(self):
        """Seconds of each step's wall time not charged to it: the round trips in it, less the
        charges of its calls (negative where a call's CPU exceeded its wall time: its threads')."""
        return np.array([w for w, _ in self.steps], np.float64) - self.charged()


def split_cpu(used, between, wall, cpus):
    """(the CPU a call used, the CPU no call can have used) of a call whose group was charged `used`
    seconds since the call before, `between` of them before its request (read then), `wall` its
    wall time and `cpus` the threads it is granted (at most the CPUs it may run on): beyond `wall`
    times `cpus`, the call's CPU was run before it and accounted late (a lump of work left running),
    or on threads it was not granted; apart too."""
    within = used - between
    beyond = max(within - wall * cpus, 0.0)
    return within - beyond, between + beyond


def unasked_pool(contestant, null):
    """Seconds of the CPU `contestant`'s group was charged that no call can have used that are its
    to be charged: their sum over its calls since its setup (outside_s), less as many times the
    null contestant's mean of the same; never below zero."""
    return max(contestant.outside_s - contestant.calls * null.outside_s / max(null.calls, 1), 0.0)


def in_call(contestant):
    """(wall, CPU) of `contestant`'s last call, the CPU only what the call can have used (the rest,
    `outside`, is spread: split_cpu)."""
    wall, cpu = contestant.last
    return wall, cpu - contestant.outside


def call_charge(wall, cpu, floor):
    """One call's charge: max(wall - the null's least round trip, CPU - the null's least CPU, 0);
    floor: (least wall, least CPU) of the null for that kind of request."""
    return max(wall - floor[0], cpu - floor[1], 0.0)

