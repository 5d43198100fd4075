"""One escaping helper per output context: every string that reaches a page or a picture goes
through the one for where it lands. Scene names, run paths and channel names are the user's text:
legal in XML, they may hold markup, script or matplotlib's math syntax."""
import html
import json
import re

_SCRIPT_UNSAFE = {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "\u2028": "\\u2028", "\u2029": "\\u2029"}


def html_text(text):
    """Text inside an HTML element (a paragraph, a cell, <title>)."""
    return html.escape(str(text), quote=False)


def html_attr(text):
    """Text inside a double- or single-quoted HTML attribute."""
    return html.escape(str(text), quote=True)


def script_json(obj):
    """JSON to embed in a <script> element: no '</script>', '<!--' or '-->' can form in it, and
    the two line separators JavaScript once refused are escaped."""
    text = json.dumps(obj, separators=(",", ":"), allow_nan=False)
    return re.sub("[<>&\u2028\u2029]", lambda m: _SCRIPT_UNSAFE[m.group()], text)


def plot_text(text):
    """Text for a matplotlib label, title or legend, shown as written: '$' starts no math."""
    return str(text).replace("$", r"\$")


_ACTIVE_SVG = re.compile(r"<\s*(script|foreignObject|iframe|object|embed)\b|\son[a-z]+\s*=|javascript:|"
                         r"(xlink:)?href\s*=\s*[\"'](?!#)", re.IGNORECASE)


def svg_is_inert(text):
    """Whether an SVG holds nothing that runs or loads: no script, event handler or outside link
    (the plots matplotlib draws hold none; anything else is shown as an <img>, where none runs)."""
    return _ACTIVE_SVG.search(text) is None


def fill(template, **values):
    """template with each __NAME__ replaced by values[NAME] in one pass: a value holding
    '__OTHER__' is left as it is, never filled in turn."""
    return re.sub(r"__([A-Z]+)__", lambda m: values[m.group(1)] if m.group(1) in values else m.group(), template)


# --- Markdown and CSV: the reports' other two contexts --------------------------------------------

# Characters that start code, bold, a link, an image, raw HTML, an entity or a cell boundary; the
# ':' of '://' and the '.' of 'www.', which GitHub's parser would turn into a live link.
_MD_SPECIAL = re.compile(r"[\\`*\[\]<>|!&]|:(?=//)|(?<=www)\.", re.IGNORECASE)


def md_text(text):
    """Text for a markdown report (a paragraph or a table cell), shown as written: every character
    that could start code, bold, a link, an image, raw HTML, an entity or a cell boundary is
    backslash-escaped (CommonMark's and GitHub's rule; html.markdown_to_html reads it back), and so
    are the ':' of '://' and the '.' of 'www.', so that no bare address becomes a link (GitHub links
    them as it parses; an escaped character is no longer one). A line break is a space (a name
    never starts a block, so # and list marks stay). Underscores stay as typed: inside a word
    (plug_in_names) no renderer takes them for emphasis."""
    return _MD_SPECIAL.sub(lambda m: "\\" + m.group(), re.sub(r"[\r\n\u2028\u2029]+", " ", str(text)))


_FORMULA = ("=", "+", "-", "@", "\t", "\r", "|")


def csv_cell(value):
    """A value for a CSV cell that a spreadsheet shows as text: a string that starts with a
    formula's first character (=, +, -, @, tab, CR, |) gets a leading quote (the usual rule,
    OWASP's), unless it is a plain number ("-0.5" stays a number). Other values pass unchanged."""
    if not isinstance(value, str) or not value.startswith(_FORMULA):
        return value
    try:
        float(value)
        return value
    except ValueError:
        return "'" + value


class CsvWriter:
    """csv.writer whose every cell goes through csv_cell: the project's one way to write CSV."""

    def __init__(self, f, **kwargs):
        import csv
        self._w = csv.writer(f, **kwargs)

    def writerow(self, row):
        return self._w.writerow([csv_cell(v) for v in row])

    def writerows(self, rows):
        for row in rows:
            self.writerow(row)
