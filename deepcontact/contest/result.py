"""How a fenced command ended, in its own words: one small record per run (DOMjudge's runguard
writes one meta record that the daemon reads). The fenced `dc` writes it as its command ends:
"in order" (it returned, or its verdict is a failure: StudyFailed, click's Exit) or "failed" (an
error, already said in its one line). A crash, a signal or os._exit writes none. dc's own process
reads it beside the exit status and publishes the staged output only when the two agree that the
command ended in order: an exit 1 alone cannot tell a failed verdict from a crash.

The record is no proof against a hostile plug-in (its code runs in the process that writes it,
and could write the whole output too); it keeps a crash from being published as a result."""
import json
import os

from ..regular import read_regular
from . import shape

ENV = "DC_RESULT_FILE"   # where the fenced command writes its record (in its private TMPDIR)
NAME = "dc-result.json"
LIMIT = 16 << 10         # bytes: a record is a few dozen; anything larger is not one
IN_ORDER, FAILED = "in order", "failed"
MESSAGE_MOST = 2000      # characters of its message (the rest is cut as it is written)
# Its form, for the one checker of every message dc reads from a fenced job or a contestant
shape.declare("result record", shape.Record({"ended": shape.Text(choices=(IN_ORDER, FAILED)),
                                             "code": shape.Whole(lowest=-shape.WHOLE_MOST),
                                             "message": shape.Text(most=MESSAGE_MOST)}, required=("ended", "code")))
# Taken from the environment as the fenced command starts (its modules are imported before any
# plug-in code runs), so that no process it starts inherits it and writes a record of its own.
_PATH = os.environ.pop(ENV, None)
_said = False


def settle(code):
    """In the fenced command, as its process ends through dc's main with `code`: where its
    command said nothing (click's own --help or usage error, a name dc could not load), its
    record from the code: in order for 0, failed for the rest (their line is said)."""
    if not _said:
        say(IN_ORDER if code in (0, None) else FAILED, code if type(code) is int else 1)


def say(ended, code, message=""):
    """In the fenced command: its record, written whole (a temporary name renamed) where ENV
    says; nothing outside a fence."""
    global _said
    path = _PATH
    if not path:
        return
    _said = True
    data = json.dumps({"ended": ended, "code": int(code), "message": str(message)[:MESSAGE_MOST]})
    part = f"{path}.part"
    try:
        with open(part, "w") as f:
            f.write(data)
        os.replace(part, path)
    except OSError:   # (a full private folder: no record, so nothing is published; the exit says why)
        pass


def read(path):
    """dc's side: the record at path as {"ended", "code", "message"}, or None where there is none
    or it is not one (a link, a FIFO, too large, not of its form: shape.py): read once, through
    a descriptor opened without following links, never blocking."""
    data = read_regular(path, LIMIT)
    if data is None:
        return None
    try:
        record = shape.parsed(data, "result record", LIMIT)
    except shape.ShapeError:
        return None
    return {"ended": record["ended"], "code": record["code"], "message": record.get("message", "")}


def ended_in_order(record, code):
    """Whether a fenced command's staged output may be published: its record says it ended in
    order, with the exit status it ended with (0, or 1 for a verdict that is a failure)."""
    return record is not None and record["ended"] == IN_ORDER and record["code"] == code and code in (0, 1)
