"""A guard against runs that would silently grow to more memory than the machine has.

Commands estimate what they will hold before they start (bodies, grid nodes x channels x
samples) and refuse above a limit, saying the estimate and how to raise the limit."""
from .errors import InputError

DEFAULT_MAX_MEMORY_GB = 8.0
# Measured with `dc simulate pile` at 20,000 circles: about 2 kB per body for the scene, the Box2D
# world and one recorded step; the writer holds up to 8 rendered steps more, at about 1.6 kB per
# body each (a settled thesis pile's step file is 160 kB for 100 circles).
BYTES_PER_BODY = 16 * 1024


def gigabytes(n):
    return n / 2 ** 30


def check_memory(estimate, limit_gb, what):
    """Refuse `what` if it needs more than limit_gb (None: the default) gigabytes."""
    limit_gb = DEFAULT_MAX_MEMORY_GB if limit_gb is None else limit_gb
    if estimate > limit_gb * 2 ** 30:
        raise InputError(f"{what} would need about {gigabytes(estimate):.3g} GB of memory, above the "
                         f"{limit_gb:g} GB limit; if the machine has it, raise the limit with --max-memory GB")
