"""XSD validation of scene and step files with lxml, errors as ``path:line:col: message``.
lxml is imported by the functions that parse: reading a step file natively needs only its path."""
import errno
import os
import stat
from functools import lru_cache
from importlib import resources

from ._box2d import DOCTYPE_REFUSED   # one text, shared with the native reader
from .errors import one_line, show_path

KINDS = ("scene", "step")


@lru_cache(maxsize=None)
def schema(kind: str) -> "etree.XMLSchema":
    from lxml import etree
    if kind not in KINDS:
        raise ValueError(f"no schema for {kind!r}")
    path = resources.files("deepcontact.schemas") / f"{kind}.xsd"
    with resources.as_file(path) as p:
        return etree.XMLSchema(etree.parse(str(p)))


def schema_path(kind: str) -> str:
    """The XSD file on disk (for independent validators such as ``xmllint --schema``)."""
    with resources.as_file(resources.files("deepcontact.schemas") / f"{kind}.xsd") as p:
        return str(p)


def parse(path):
    """Parse an XML file, keeping line numbers. Raises etree.XMLSyntaxError, or OSError for what
    is not a regular file (a FIFO would block the parser forever)."""
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise OSError(errno.EINVAL, "not a regular file", str(path))
    from lxml import etree
    parser = etree.XMLParser(remove_blank_text=False, resolve_entities=False, no_network=True, load_dtd=False,
                             huge_tree=False)
    return etree.parse(str(path), parser)


def has_doctype(tree):
    """Our formats have no DTD: entities would hide values from the schema (or read other files)."""
    return tree.docinfo.internalDTD is not None or bool(tree.docinfo.doctype)


def validate(path, kind=None):
    """Returns (kind, tree or None, [error lines]). The kind comes from the root element."""
    kind, tree, errors = _validate(path, kind)
    return kind, tree, [one_line(e) for e in errors]


def _validate(path, kind):
    from lxml import etree
    shown = show_path(path)
    try:
        tree = parse(path)
    except etree.XMLSyntaxError as e:
        line, col = e.position if e.position else (e.lineno or 0, 0)
        return kind, None, [f"{shown}:{line}:{col}: {e.msg}"]
    except OSError as e:
        return kind, None, [f"{shown}:0:0: cannot read: {e.strerror or e}"]
    if has_doctype(tree):
        return kind, None, [f"{shown}:1:0: {DOCTYPE_REFUSED}"]
    root = tree.getroot().tag
    if kind is None:
        if root not in KINDS:
            return None, tree, [f"{shown}:{tree.getroot().sourceline}:0: root element <{root}> "
                                f"is neither <scene> nor <step>"]
        kind = root
    xsd = schema(kind)
    if xsd.validate(tree):
        return kind, tree, []
    return kind, tree, [f"{shown}:{e.line}:{e.column}: {e.message}" for e in xsd.error_log]
