"""Self-contained HTML pages: the project's markdown reports turned into one file that reads
offline (no script, no network), with each plot's SVG inlined in place of its PNG.

Only the markdown the reports write is understood: headings, paragraphs, pipe tables, bullet
lists, `code`, **bold** and ![alt](plot.png) images (replaced by plot.svg from the same folder
where it exists, else embedded as a data: URL). Only the pictures the command itself drew (the
names it passes as `pictures`) are inlined: an image line anywhere else, say from a run path that
holds markdown, is shown as the text it is, so no page inlines a file from the reader's disk."""
import base64
import re
from pathlib import Path

from .escape import html_attr, html_text, svg_is_inert

STYLE = """
body { font: 15px/1.45 system-ui, sans-serif; margin: 2em auto; max-width: 72em; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
th { background: #f2f2f2; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1em 0; }
figure svg { max-width: 100%; height: auto; }
code { background: #f4f4f4; padding: 0 0.2em; }
"""


_ESCAPED = re.compile(r"\\([!-/:-@\[-`{-~])")   # markdown's backslash escapes (escape.md_text)


def _inline(text):
    """Escapes text, then turns `code` and **bold** into tags; a backslash-escaped character is
    that character, as text (never markup: escape.md_text's names and paths)."""
    kept = []

    def keep(m):
        kept.append(m.group(1))
        return f"\x00{len(kept) - 1}\x00"
    out = html_text(_ESCAPED.sub(keep, text.replace("\x00", "")))
    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", out)
    out = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", out)
    return re.sub("\x00(\\d+)\x00", lambda m: html_text(kept[int(m.group(1))]), out)


def _cells(line):
    """A table row's cells: split at each | that is not backslash-escaped."""
    cells, cell, chars = [], [], iter(line.strip())
    for c in chars:
        if c == "\\":
            cell.append(c + next(chars, ""))
        elif c == "|":
            cells.append("".join(cell))
            cell = []
        else:
            cell.append(c)
    cells.append("".join(cell))
    if cells and not cells[0].strip():
        cells = cells[1:]
    if cells and not cells[-1].strip():
        cells = cells[:-1]
    return [c.strip() for c in cells]


def _figure(alt, target, folder):
    path = Path(folder) / target
    svg = path.with_suffix(".svg")
    if svg.is_file():
        text = svg.read_text(encoding="utf-8")
        if svg_is_inert(text):
            text = text[text.index("<svg"):] if "<svg" in text else text   # drop the XML declaration and DOCTYPE
            return f'<figure aria-label="{html_attr(alt)}">{text}</figure>'
        data = base64.b64encode(svg.read_bytes()).decode()   # in an <img>, no script of it runs
        return f'<figure><img alt="{html_attr(alt)}" src="data:image/svg+xml;base64,{data}"></figure>'
    if path.is_file():
        data = base64.b64encode(path.read_bytes()).decode()
        return f'<figure><img alt="{html_attr(alt)}" src="data:image/png;base64,{data}"></figure>'
    return f"<p><em>({html_text(alt)}: {html_text(target)} is missing)</em></p>"


def _table(lines):
    head = _cells(lines[0])
    align = ["num" if c.endswith(":") else "" for c in _cells(lines[1])] if len(lines) > 1 else []
    out = ["<table>", "<tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"]
    for line in lines[2:]:
        cells = _cells(line)
        out.append("<tr>" + "".join(
            f'<td class="{align[i]}">{_inline(c)}</td>' if i < len(align) and align[i] else f"<td>{_inline(c)}</td>"
            for i, c in enumerate(cells)) + "</tr>")
    return "\n".join(out + ["</table>"])


def markdown_to_html(text, folder, title, pictures=()):
    """One HTML page from the report's markdown; the images named in `pictures` (file names the
    command drew in `folder`) are inlined from there, any other image line is text."""
    pictures = set(pictures)
    body, block = [], []
    lines = text.splitlines()
    i = 0

    def flush():
        if block:
            body.append("<p>" + _inline(" ".join(block)) + "</p>")
            block.clear()
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        image = re.fullmatch(r"!\[([^\]]*)\]\(([^)\s/]+)\)", stripped)
        image = image if image and image.group(2) in pictures else None
        if not stripped:
            flush()
        elif stripped.startswith("#"):
            flush()
            level = min(len(stripped) - len(stripped.lstrip("#")), 6)
            body.append(f"<h{level}>{_inline(stripped[level:].strip())}</h{level}>")
        elif image:
            flush()
            body.append(_figure(image.group(1), image.group(2), folder))
        elif stripped.startswith("|"):
            flush()
            rows = []
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append(lines[i])
                i += 1
            body.append(_table(rows))
            continue
        elif stripped.startswith(("- ", "* ")):
            flush()
            items = []
            while i < len(lines) and lines[i].strip().startswith(("- ", "* ")):
                items.append(f"<li>{_inline(lines[i].strip()[2:])}</li>")
                i += 1
            body.append("<ul>" + "".join(items) + "</ul>")
            continue
        else:
            block.append(stripped)
        i += 1
    flush()
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html_text(title)}</title><style>{STYLE}</style></head>\n<body>\n"
            + "\n".join(body) + "\n</body></html>\n")
