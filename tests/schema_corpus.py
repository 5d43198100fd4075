"""The step schema's own edge cases, generated from schemas/step.xsd and common.xsd (walked here
with lxml, apart from the table's compiler in deepcontact/step/strict.py): one step file holding
every element and attribute the schema declares, and its mutations, one rule each: an element
removed, repeated, unknown, namespaced; text, CDATA, character references, comments inside each
element; each attribute removed; unknown, namespaced and XML Schema instance (xsi:) attributes
added; each attribute's value replaced by the lexical edge cases of its type (signed zeros,
leading zeros, exponents, INF and NaN, float32's bounds, white space, empty strings,
enumeration neighbours). tests/test_schema_table.py judges each by the table and by the XSD.
"""
from dataclasses import dataclass, replace
from pathlib import Path

from lxml import etree

from deepcontact.schema import schema_path

XS = "{http://www.w3.org/2001/XMLSchema}"
XSI = 'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'

# Every attribute value below is as written between the quotes (escaped where XML needs it).
NUMBERS = [
    "0", "-0", "+0", "00", "-00", "+00", "1", "+1", "-1", "01", "+01", "-01", "007", "0" * 30 + "7", "-" + "0" * 30,
    "2147483647", "2147483648", "-2147483648", "-2147483649", "4294967295", "4294967296", "-4294967295",
    "99999999999999999999", "1" + "0" * 30, "-1" + "0" * 30,
    "1.5", "-1.5", "1.", ".5", "-.5", "+.5", ".", "-.", "0.0", "-0.0", "+0.0", "00.00",
    "1e0", "1E3", "-1e3", "1e-3", "+.5e-3", "1e+3", "1.e5", ".5e5", "0e0", "-0e0", "-0e-5",
    "1e", "1E+", "1e-", "-1e", "-0e", "0e", "e5", "1e5.5", "1e1e1", "1ee1",
    "1e-38", "1e-45", "1.4e-45", "1e-46", "7e-46", "-1e-46", "1e-50", "-1e-50", "1e-400",
    "1e38", "1e39", "-1e39", "1e400", "-1e400",
    "3.4028234e38", "3.40282347E38", "3.4028235e38", "-3.4028235e38", "3.40282356e38", "3.4028235677973366e38",
    "3.40282357e38", "-3.40282357e38", "340282356779733661637539395458142568447",
    "340282356779733661637539395458142568448", "340282356779733661637539395458142568449",
    "0." + "0" * 44 + "1", "0." + "0" * 60 + "1", "1" * 70, "-" + "1" * 70, "0" * 70 + "1",
    "INF", "-INF", "+INF", "NaN", "-NaN", "+NaN", "inf", "nan", "Infinity", "-Infinity", " INF", "NaN ",
    "0x10", "0x1p3", "1f", "1d", "1_000", "1,5", "1 2", "- 1", "+-1", "--1", "1-", "١",
    " 1", "1 ", " 1 ", "&#9;1", "1&#10;", "&#13;1", "&#160;1", " -0 ", " +0", "&#9;-0",
    "", " ", "+", "-", "true", "a",
]
BOOLEANS = ["true", "false", "1", "0", " true ", "&#9;false", "false&#10;", "TRUE", "True", "yes", "no",
            "2", "-0", "+1", "01", "-1", "1.0", "t", "", " ", "tr ue"]
TOKENS = ["", " ", "a", " a", "a ", "a  b", "a&#9;b", "&#10;a&#10;", "\u00e9", "a&amp;b", "&lt;", "&#160;"]
SHORT = ["", "-0", " 1", "a"]   # for an attribute whose type another one showed in full

# Inside an element: text, CDATA and character references (white space or not), markup that is
# no text at all; the few, in every element, and the rest in the first of each kind.
FEW_CONTENTS = [" ", "&#160;", "x", "<![CDATA[]]>"]
CONTENTS = [*FEW_CONTENTS, "&#10;", "&#32;", "&#9;&#13;", "&amp;", "<![CDATA[ ]]>", "<![CDATA[x]]>", "<!-- c -->",
            "<?pi x?>", "<bogus/>", " <bogus/> "]

# Attributes added to an element: unknown ones, other namespaces', the XML Schema instance's.
FEW_EXTRA = ['bogus="1"', f'{XSI} xsi:nil="true"', f'{XSI} xsi:foo="1"']
EXTRA = [*FEW_EXTRA, 'xml:lang="en"', 'xml:space="preserve"', 'xmlns:q="urn:q" q:a="1"', f'{XSI} xsi:nil="false"',
         f'{XSI} xsi:nil="maybe"', f'{XSI} xsi:type="step"', f'{XSI} xsi:type="bogus"', f'{XSI} xsi:type="xs:anyType"',
         f'{XSI} xsi:schemaLocation="urn:x step.xsd"', f'{XSI} xsi:schemaLocation="a"',
         f'{XSI} xsi:noNamespaceSchemaLocation="step.xsd"', f'{XSI} xsi:noNamespaceSchemaLocation=""',
         'xmlns:s="http://www.w3.org/2001/XMLSchema-instance" s:nil="true"']


@dataclass(frozen=True)
class Node:
    """An element of the generated file, as written."""
    name: str
    attributes: tuple          # ((name, value as written), ...)
    children: tuple
    type_name: str | None      # its declared type's name, where it has one
    content: str = ""          # markup written before its children
    open_close: bool = False   # written <a></a> though empty

    def xml(self, spans=None):
        """The element as text; spans: {id(node): (start, end)} of it and every element inside
        filled in (offsets within this text)."""
        attributes = "".join(f" {a}" if v is None else f' {a}="{v}"' for a, v in self.attributes)
        inner, at = self.content, len(self.name) + len(attributes) + 2 + len(self.content)
        for child in self.children:
            inside = {} if spans is not None else None
            text = child.xml(inside)
            if spans is not None:
                spans.update({k: (at + b, at + e) for k, (b, e) in inside.items()})
            inner, at = inner + text, at + len(text)
        text = (f"<{self.name}{attributes}/>" if not inner and not self.open_close
                else f"<{self.name}{attributes}>{inner}</{self.name}>")
        if spans is not None:
            spans[id(self)] = (0, len(text))
        return text


class _File:
    """The generated file's text, and where each element lies in it."""

    def __init__(self, root):
        self.root, self.spans = root, {}
        self.text = root.xml(self.spans)

    def xml(self, node, edit):
        """The text with `node` written as `edit(node)` says."""
        start, end = self.spans[id(node)]
        return self.text[:start] + edit(node) + self.text[end:]


def _local(name):
    return name.rsplit("}", 1)[-1].split(":")[-1]


def _parts(node):
    return [p for p in node if not callable(p.tag)]   # (no comments)


class _Schema:
    """The step schema's declarations, as lxml reads them."""

    def __init__(self):
        path = Path(schema_path("step"))
        step = etree.parse(str(path)).getroot()
        docs = [step, *(etree.parse(str(path.parent / i.get("schemaLocation"))).getroot()
                        for i in step.findall(f"{XS}include"))]
        self.named = {(_local(t.tag), t.get("name")): t for d in docs for t in _parts(d) if t.get("name")}
        self.root = self.named["element", "step"]

    def simple(self, attribute):
        """(the XSD built-in type under an attribute's type, its enumeration)."""
        node = attribute.find(f"{XS}simpleType")
        name = attribute.get("type")
        enumeration = []
        while node is not None or not name.startswith("xs:"):
            node = node if node is not None else self.named["simpleType", name]
            restriction = node.find(f"{XS}restriction")
            enumeration = enumeration or [e.get("value") for e in restriction.findall(f"{XS}enumeration")]
            node, name = None, restriction.get("base")
        return _local(name), enumeration

    def valid(self, attribute):
        """A value the attribute's type holds."""
        if attribute.get("fixed") is not None:
            return attribute.get("fixed")
        builtin, enumeration = self.simple(attribute)
        if enumeration:
            return enumeration[0]
        return {"boolean": "true", "token": "a", "string": "a"}.get(builtin, "1")

    def complex_type(self, element):
        inline = element.find(f"{XS}complexType")
        return inline if inline is not None else self.named["complexType", element.get("type")]

    def instance(self, element):
        """The element with every attribute it declares and each child it may hold (as often as
        it must, at least once), as a Node."""
        ctype = self.complex_type(element)
        attributes = tuple((a.get("name"), self.valid(a)) for a in ctype.findall(f"{XS}attribute"))
        if ctype.find(f"{XS}anyAttribute") is not None:
            attributes += (("extra", "1"),)
        children = []
        for part in _parts(ctype.find(f"{XS}sequence")) if ctype.find(f"{XS}sequence") is not None else ():
            members = ([part] if _local(part.tag) == "element"
                       else _parts(self.named["group", part.get("ref")].find(f"{XS}choice")))
            for member in members:
                children += [self.instance(member) for _ in range(max(int(part.get("minOccurs", "1")), 1))]
        return Node(element.get("name"), attributes, tuple(children), element.get("type"))


def _nodes(node):
    yield node
    for child in node.children:
        yield from _nodes(child)


def _declarations(schema):
    """Each node's attribute declarations (nodes and declarations met in the same order)."""
    out = []

    def walk(element):
        ctype = schema.complex_type(element)
        out.append(ctype.findall(f"{XS}attribute"))
        if ctype.find(f"{XS}sequence") is None:
            return
        for part in _parts(ctype.find(f"{XS}sequence")):
            members = ([part] if _local(part.tag) == "element"
                       else _parts(schema.named["group", part.get("ref")].find(f"{XS}choice")))
            for member in members:
                for _ in range(max(int(part.get("minOccurs", "1")), 1)):
                    walk(member)
    walk(schema.root)
    return out


def _structure(whole, node, shown):
    """(label, text) of the mutations of one element's place, name and content: every content
    and added attribute in the first element of each kind (the root, of empty content, of
    element content, taking any attribute), a few in the others."""
    kind = (node is whole.root, bool(node.children), any(a == "extra" for a, _ in node.attributes))
    full = kind not in shown
    shown.add(kind)
    where = f"<{node.name}>"
    edits = {
        "removed": lambda n: "",
        "repeated": lambda n: n.xml() * 2,
        "an unknown element before it": lambda n: "<bogus/>" + n.xml(),
        "in a namespace": lambda n: replace(n, attributes=(("xmlns", "urn:x"), *n.attributes)).xml(),
        "prefixed in a namespace": lambda n: replace(n, name=f"q:{n.name}",
                                                     attributes=(("xmlns:q", "urn:q"), *n.attributes)).xml(),
        "undeclaring the default namespace": lambda n: replace(n, attributes=(("xmlns", ""), *n.attributes)).xml(),
        "renamed": lambda n: replace(n, name=n.name + "x").xml(),
        "written open and closed": lambda n: replace(n, open_close=True).xml(),
    }
    for label, edit in edits.items():
        yield f"{where} {label}", whole.xml(node, edit)
    for content in CONTENTS if full else FEW_CONTENTS:
        yield f"{where} holding {content!r}", whole.xml(node, lambda n: replace(n, content=content).xml())
    for extra in EXTRA if full else FEW_EXTRA:
        yield f"{where} with {extra}", whole.xml(node, lambda n: replace(n, attributes=(*n.attributes,
                                                                                        (extra, None))).xml())


def _values(whole, node, declarations, shown):
    """(label, text) of the mutations of one element's attributes: each removed, each value
    replaced by its type's edge cases (in full for the first attribute of each type)."""
    for k, (name, _) in enumerate(node.attributes):
        def with_value(value, k=k):
            attributes = list(node.attributes)
            if value is None:
                del attributes[k]
            else:
                attributes[k] = (attributes[k][0], value)
            return whole.xml(node, lambda n: replace(n, attributes=tuple(attributes)).xml())
        yield f"<{node.name} {name}> removed", with_value(None)
        declaration = next((d for d in declarations if d.get("name") == name), None)
        if declaration is None:   # (an attribute the wildcard allows)
            continue
        for value in _edges(declaration, shown):
            yield f"<{node.name} {name}={value!r}>", with_value(value)


def _edges(declaration, shown):
    """The values to try in an attribute: its type's edge cases in full the first time the type
    is met (its name, or its inline definition, and its fixed value), else a few."""
    key = (declaration.get("type") or etree.tostring(declaration), declaration.get("fixed"))
    if key in shown:
        return SHORT
    shown.add(key)
    builtin, enumeration = SCHEMA.simple(declaration)
    neighbours = [v for e in enumeration for v in (e + "x", e[:-1], e.upper(), f" {e} ", f"{e}&#9;",
                                                   e.replace("_", " "), e.replace("_", "  "))]
    return [*enumeration, *neighbours, *{"boolean": BOOLEANS, "token": TOKENS, "string": TOKENS}.get(builtin, NUMBERS),
            *(TOKENS if builtin != "token" else BOOLEANS)]


SCHEMA = _Schema()


def corpus():
    """[(label, text)]: the generated valid file first, then each of its mutations."""
    root = SCHEMA.instance(SCHEMA.root)
    whole = _File(root)
    head = '<?xml version="1.0" encoding="UTF-8"?>\n'
    out = [("the generated file", head + whole.text)]
    kinds, types = set(), set()
    for node, declarations in zip(_nodes(root), _declarations(SCHEMA)):
        out += [(label, head + text) for label, text in _structure(whole, node, kinds)]
        out += [(label, head + text) for label, text in _values(whole, node, declarations, types)]
    out += [("<step> holding text after its end", head + whole.text + "x"),
            ("a second root", head + whole.text * 2)]
    return out
