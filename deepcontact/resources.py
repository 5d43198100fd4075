"""Guards against runs that would silently grow to more memory or disk than the machine has.

Commands estimate what they will hold or write before they start (bodies, grid nodes x channels
x samples, steps x bytes per step) and refuse above a limit, saying the estimate and the limit."""
import shutil
from pathlib import Path

from .errors import InputError

DEFAULT_MAX_MEMORY_GB = 8.0
# Measured with `dc simulate pile` at 20,000 circles: about 2 kB per body for the scene, the Box2D
# world and one recorded step; the writer holds up to 8 rendered steps more, at about 1.6 kB per
# body each (a settled thesis pile's step file is 160 kB for 100 circles).
BYTES_PER_BODY = 16 * 1024
# A settled thesis pile's step file: 160 kB for 101 bodies (about 700 bytes a body, 540 a contact
# point, two points a body), measured with `dc simulate pile`.
STEP_BYTES_PER_BODY = 1600
# What a step file holds besides: 540 bytes a contact point, and a body's fixtures make contact
# points (up to two a fixture in a settled pile: a circle on the floor and one neighbour below).
STEP_BYTES_PER_BODY_RECORD = 700
STEP_BYTES_PER_CONTACT = 540
CONTACT_POINTS_PER_FIXTURE = 2


def step_bytes(bodies, fixtures):
    """About what one step file of a scene takes: the bodies' records and the contact points its
    fixtures make (the thesis pile: 101 bodies, 101 fixtures, 180 kB against 160 kB measured)."""
    return 1024 + STEP_BYTES_PER_BODY_RECORD * bodies + STEP_BYTES_PER_CONTACT * CONTACT_POINTS_PER_FIXTURE * fixtures


# A gzip step file (dc simulate --compress, level 1) is about a sixth of the plain one on the
# thesis pile (measured: 0.168); the disk estimate divides by 4 to stay on the safe side.
COMPRESSION_RATIO = 4


# What a generated scene holds in Python (its bodies, shapes and vertices): about 1.1 kB a body for
# a stack of boxes (`generate("stack", 0, {"count": "100000"})`: 1,062 bytes a body of peak
# memory), rounded up.
SCENE_BYTES_PER_BODY = 2048


def machine_memory():
    """This machine's physical memory in bytes (None where it cannot be read)."""
    import os
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def gigabytes(n):
    return n / 2 ** 30


def check_memory(estimate, limit_gb, what):
    """Refuse `what` if it needs more than limit_gb (None: the default) gigabytes."""
    limit_gb = DEFAULT_MAX_MEMORY_GB if limit_gb is None else limit_gb
    if estimate > limit_gb * 2 ** 30:
        raise InputError(f"{what} would need about {gigabytes(estimate):.3g} GB of memory, above the "
                         f"{limit_gb:g} GB limit; if the machine has it, raise the limit with --max-memory GB")


# What one step may cost, in iterations times bodies (each iteration counted as 16 bodies more, its
# own overhead): about two minutes of sweeps on this project's machine at 57 ns a body-iteration.
# Box2D's own iterations and v3's substeps run inside Box2D, where no signal can stop them, so a
# count that would run for hours (2^31) is refused before any work, with the figure, as memory is.
MAX_STEP_WORK = 2e9


def check_step_work(bodies, iterations, what):
    """Refuse `what` (iterations per step over `bodies` bodies) above MAX_STEP_WORK a step."""
    work = iterations * (bodies + 16)
    if work > MAX_STEP_WORK:
        raise InputError(f"{what} over {bodies:,} bodies is about {work:.2g} body-iterations a step, above the "
                         f"{MAX_STEP_WORK:.0e} one step may cost (minutes); lower it")


def free_disk(path):
    """Free bytes on the file system that path (or its nearest existing parent) is on."""
    parent = Path(path).resolve()
    while not parent.exists():
        parent = parent.parent
    return shutil.disk_usage(parent).free


def check_disk(estimate, path, limit_gb, what):
    """Refuse `what` if it would write more than the free space at path, or than limit_gb."""
    free = free_disk(path)
    if estimate > free:
        raise InputError(f"{what} would take about {gigabytes(estimate):.3g} GB on disk; {gigabytes(free):.3g} GB "
                         f"are free there", path)
    if limit_gb is not None and estimate > limit_gb * 2 ** 30:
        raise InputError(f"{what} would take about {gigabytes(estimate):.3g} GB on disk, above the --max-disk "
                         f"limit of {limit_gb:g} GB", path)
