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


# A compressed file inflates to at most this many times its size (at least MIN_INFLATED bytes):
# the native reader's bound (native/step_read.cpp), so lxml, which inflates gzip by itself, is
# held to it too. Our step files inflate about 6x.
MAX_RATIO = 64
MIN_INFLATED = 16 << 20


def parse(path):
    """Parse an XML file (or a gzip-compressed one, inflated within MAX_RATIO), keeping line
    numbers. Raises etree.XMLSyntaxError, or OSError for what is not a regular file (a FIFO would
    block the parser forever) or inflates past the bound."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        raise OSError(errno.EINVAL, "not a regular file", str(path))
    from lxml import etree
    parser = etree.XMLParser(remove_blank_text=False, resolve_entities=False, no_network=True, load_dtd=False,
                             huge_tree=False)
    with open(path, "rb") as f:
        if f.read(2) == b"\x1f\x8b":
            import io
            return etree.parse(io.BytesIO(_inflated(path, max(MIN_INFLATED, MAX_RATIO * st.st_size))), parser)
    return etree.parse(str(path), parser)


def file_bytes(path):
    """A file's bytes, a gzip-compressed one inflated within the bound every reader holds it to
    (OSError past it, before holding more than the bound)."""
    with open(path, "rb") as f:
        compressed = f.read(2) == b"\x1f\x8b"
    if not compressed:
        with open(path, "rb") as f:
            return f.read()
    return _inflated(path, max(MIN_INFLATED, MAX_RATIO * os.stat(path).st_size))


def _inflated(path, limit):
    """A gzip file's bytes, or OSError once they pass `limit` (before holding more than it)."""
    import zlib
    out, size = [], 0
    inflate = zlib.decompressobj(16 + zlib.MAX_WBITS)
    with open(path, "rb") as f:
        while chunk := f.read(1 << 16):
            try:
                piece = inflate.decompress(chunk, limit + 1 - size)
                while piece:
                    out.append(piece)
                    size += len(piece)
                    if size > limit:
                        raise OSError(errno.EFBIG, f"inflates to more than {MAX_RATIO} times its compressed size",
                                      str(path))
                    piece = inflate.decompress(inflate.unconsumed_tail, limit + 1 - size)
            except zlib.error as e:
                raise OSError(errno.EINVAL, f"a damaged compressed file ({e})", str(path)) from None
    return b"".join(out)


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
