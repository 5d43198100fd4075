"""Checking files against the schemas, one error a line as ``path:line:col: message``.

Step files are checked in one streaming pass against the step schema's table as they are read
(strict.py; as .xml or .xml.gz): a file it accepts is valid, and the XSD itself judges every
other (one it refuses or leaves to it) and lists its errors; anything whose root is not <step>
(scene files, a DOCTYPE, a stray XML file) goes through lxml (schema.validate). A step file is
also checked to belong to the simulation it lies in, where that is known."""
from .. import schema
from .._box2d import StepFileError, validate_step_file
from ..errors import InputError, one_line, show_path
from .reader import check_origin, read_step, step_schema
from .records import check_solve, check_solve_itself

MAX_ERRORS = 100   # per file: past these, a broken file says nothing new


def check_file(path, origin=None):
    """(kind, error lines): kind "step", "scene" or None. origin: (scene, seed, engine) of the
    simulation the file lies in, and optionally its run's pgs record (None: the project's solver
    did not step it), or None."""
    return check_and_read(path, origin)[:2]


def check_and_read(path, origin=None):
    """check_file's (kind, error lines), and the step the pass read: (header, bodies, contacts) of
    a valid step file, else None (what dc validate --residuals judges, without reading it again)."""
    try:   # a valid step file (nearly every file): checked against the schema's table and read in one pass
        step = read_step(path, validate=True)
    except InputError:   # not one: the second pass below lists the XSD's errors (up to MAX_ERRORS), or says why
        step = None
    if step is not None:
        lines = _semantic_errors(path, step, origin)
        return "step", lines, None if lines else step
    shown = show_path(path)
    try:
        root, scene, seed, errors = validate_step_file(str(path), step_schema(), MAX_ERRORS)
    except StepFileError as e:   # cannot be read at all (missing, not a regular file, cut gzip)
        message, line = e.args
        return None, [one_line(f"{shown}:{line}:0: {message}")], None
    if root != "step":
        kind, _, lines = schema.validate(path)
        return kind, lines, None
    lines = [one_line(f"{shown}:{line}:{column}: {message}") for line, column, message in sorted(errors)]
    if not lines:
        try:
            step = read_step(path, validate=False)
        except InputError as e:
            return "step", [one_line(f"{show_path(e.path)}:{e.line or 0}:0: {e.message}")], None
        lines = _semantic_errors(path, step, origin)
    return "step", lines, None if lines else step


def _semantic_errors(path, step, origin):
    """What the schema cannot say of a valid step file, as error lines: contacts naming bodies of
    their own step, its <solve> agreeing with itself, the file where it belongs and its <solve>
    agreeing with its run."""
    header, bodies, contacts = step
    try:
        _contacts_name_its_bodies(bodies, contacts, path)
        if header.get("solve") is not None:   # (in a run or alone: its record is consistent)
            check_solve_itself(header["solve"], path)
        if origin is not None:
            scene_of, seed_of, engine, *record = origin
            check_origin(header, scene_of, seed_of, path, engine)
            if record:   # (the run's pgs record, or None: its <solve> agrees with the run)
                check_solve(header.get("solve"), record[0], path)
    except InputError as e:
        return [one_line(f"{show_path(e.path)}:{e.line or 0}:0: {e.message}")]
    return []


def _contacts_name_its_bodies(bodies, contacts, path):
    """Every body of the step is there once, and every contact names bodies of its own step (the
    schema cannot say: master="999" of 101 bodies validated); InputError naming the file and the
    body or contact otherwise."""
    import numpy as np
    index = np.asarray(bodies.get("index", ()))
    known, seen = np.unique(index, return_counts=True)
    if len(known) != len(index):
        body = int(known[np.flatnonzero(seen > 1)[0]])
        raise InputError(f'body {body} is recorded twice (two <body index="{body}">)', path)
    stray = stray_contact(bodies, contacts)
    if stray is not None:
        row, side, body = stray
        attribute = {"body_a": "master", "body_b": "slave"}[side]
        raise InputError(f"contact {row} names body {body} ({attribute}), but the step has no body {body} "
                         f"({len(bodies.get('index', ()))} bodies)", path)


def stray_contact(bodies, contacts):
    """The first contact naming a body its step has not, as (contact row, "body_a" or "body_b",
    body), or None. Contacts name bodies by their index in the scene (the bodies' `index`
    column), not by row: a removed body leaves a gap, and the bodies after it keep their index."""
    import numpy as np
    known = np.asarray(bodies.get("index", ()))
    for side in ("body_a", "body_b"):
        ids = np.asarray(contacts.get(side, ()))
        bad = np.flatnonzero(~np.isin(ids, known)) if len(ids) else ()
        if len(bad):
            return int(bad[0]), side, int(ids[bad[0]])
    return None
