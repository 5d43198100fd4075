"""Tiny helpers for writing XML text (xml.sax.saxutils drags in urllib: 15 ms at start-up)."""
import re

_ESCAPES = str.maketrans({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;",
                          "\n": "&#10;", "\r": "&#13;", "\t": "&#9;"})


# What XML 1.0 cannot hold at all, even as a character reference: a control character (a plug-in's
# name or version held one, and 150 of 151 step files were then invalid), a lone surrogate, U+FFFE/F.
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def _shown(match):
    c = ord(match.group())
    return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"


def held(value) -> str:
    """The text an attribute holds of a value, as a reader reads it back: a character XML cannot
    hold written as its Python escape (\\x01)."""
    text = str(value)
    return _NOT_XML.sub(_shown, text) if _NOT_XML.search(text) else text


def quoteattr(value) -> str:
    """An attribute value in double quotes, escaped; a character XML cannot hold is written as its
    Python escape (\\x01), so the file stays valid and the value readable."""
    return '"' + held(value).translate(_ESCAPES) + '"'
