"""The step schema as a table the native reader checks every file against as it reads it.

`dc validate` held every step file to schemas/step.xsd through libxml2's validator, which took
three quarters of its time (1.5 of 2 ms a file; a file is written in about 1). The same rules,
compiled here from the XSD itself (no second copy to drift), are checked by the native reader in
the one streaming pass that reads the file: which elements, in which order and how many (a
sequence, a choice, minOccurs and maxOccurs), which attributes (required, allowed, any other
where the schema says so), each attribute's type (a finite float32 with its bounds, a whole
number with its bounds, a boolean, an enumeration, a fixed value, a token) and no text where the
schema allows none.

One verdict: a file the table accepts is valid, and no XSD runs on it; every other file goes to
the XSD itself, the authority, which judges it and says what is wrong. So the table accepts only
what libxml2's validator accepts, and does not decide (it defers: the XSD runs) the forms on which
libxml2's versions differ or that it does not read: white space around an xs:int, a sign on an
xs:unsignedInt, an exponent without digits, a CDATA section, an xsi:type. tests/test_schema_table.py
is the proof: the schema's own edge cases, generated from the XSD, each judged by the table, by
the native validator (the system's libxml2) and by lxml's (its own libxml2), in `make test`.
"""
from functools import lru_cache
from pathlib import Path

from ..schema import schema_path

XS = "{http://www.w3.org/2001/XMLSchema}"

# The XSD's built-in types this schema uses: (kind, low, low exclusive, high). libxml2 reads the
# whole numbers of xs:int, xs:unsignedInt and xs:integer each its own way (native/step_strict.hpp).
_BUILTIN = {
    "float": ("float", None, False, None), "int": ("int", -2 ** 31, False, 2 ** 31 - 1),
    "unsignedInt": ("unsigned", 0, False, 2 ** 32 - 1), "positiveInteger": ("integer", 1, False, None),
    "boolean": ("boolean", None, False, None), "token": ("token", None, False, None),
    "string": ("string", None, False, None),
}
KINDS = ("float", "int", "unsigned", "integer", "boolean", "token", "string")

# The attributes of a declaration the table says all of: any other (nillable, a reference, a
# substitution group, a prohibited attribute...) fails the compilation.
_ELEMENT_KEYS = {"name", "type", "minOccurs", "maxOccurs"}
_ATTRIBUTE_KEYS = {"name", "type", "use", "fixed", "default"}


class Unsupported(ValueError):
    """A construct of the XSD the table cannot say: compiling fails (and the tests with it) rather
    than check a file less strictly than the schema."""


def _local(name):
    """A tag's or a type's name without its namespace ("{...}element", "xs:float")."""
    return name.rsplit("}", 1)[-1].split(":")[-1]


def _plain(declaration, keys):
    """Unsupported where a declaration says more than the table does."""
    extra = set(declaration.keys()) - keys
    if extra:
        raise Unsupported(f"<xs:{_local(declaration.tag)} {' '.join(sorted(extra))}> "
                          f"(of {declaration.get('name')})")


class _Compiler:
    def __init__(self, root):
        self.types, self.complex, self.groups = {}, {}, {}
        for doc in self._documents(root):
            for t in doc.findall(f"{XS}simpleType"):
                self.types[t.get("name")] = t
            for t in doc.findall(f"{XS}complexType"):
                self.complex[t.get("name")] = t
            for g in doc.findall(f"{XS}group"):
                self.groups[g.get("name")] = g
        self.root = root
        self.decls = []

    def _documents(self, root):
        from lxml import etree
        docs, folder = [root], Path(schema_path("step")).parent
        for inc in root.findall(f"{XS}include"):
            docs.append(etree.parse(str(folder / inc.get("schemaLocation"))).getroot())
        return docs

    def simple(self, node):
        """(kind, low, low exclusive, high, enumeration) of a simpleType element or a type name."""
        if isinstance(node, str):
            name = _local(node)
            if node.startswith("xs:"):
                if name not in _BUILTIN:
                    raise Unsupported(f"the XSD type xs:{name}")
                return (*_BUILTIN[name], ())
            node = self.types[name]
        restriction = node.find(f"{XS}restriction")
        if restriction is None:
            raise Unsupported("a simpleType that is not a restriction")
        kind, low, low_open, high, enum = self.simple(restriction.get("base"))
        for facet in restriction:
            tag, value = _local(facet.tag), facet.get("value")
            if tag == "minInclusive":
                low, low_open = float(value), False
            elif tag == "minExclusive":
                low, low_open = float(value), True
            elif tag == "maxInclusive":
                high = float(value)
            elif tag == "enumeration":
                enum = (*enum, value)
            elif not callable(facet.tag):   # (a comment is no facet)
                raise Unsupported(f"the facet {tag}")
        return kind, low, low_open, high, enum

    def attributes(self, ctype):
        """([(name, kind, required, low, low exclusive, high, enumeration, fixed)], any other allowed)."""
        out, anything = [], False
        for a in ctype:
            tag = _local(a.tag) if not callable(a.tag) else ""
            if tag == "attribute":
                _plain(a, _ATTRIBUTE_KEYS)
                if a.get("use", "optional") not in ("optional", "required"):
                    raise Unsupported(f"the attribute {a.get('name')} used {a.get('use')}")
                inline = a.find(f"{XS}simpleType")
                kind, low, low_open, high, enum = self.simple(inline if inline is not None else a.get("type"))
                out.append((a.get("name"), kind, a.get("use") == "required", low, low_open, high, enum,
                            a.get("fixed")))
            elif tag == "anyAttribute":
                # (any attribute, undeclared: the table checks no wildcard's namespaces or contents)
                if a.get("namespace", "##any") != "##any" or a.get("processContents") not in ("lax", "skip"):
                    raise Unsupported("an anyAttribute other than any namespace's, lax or skip")
                anything = True
        return out, anything

    def element(self, node):
        """The index of the declaration of the element `node` (an xs:element), compiled."""
        _plain(node, _ELEMENT_KEYS)
        ctype = node.find(f"{XS}complexType")
        if ctype is None:
            type_name = node.get("type")
            if type_name is None:
                raise Unsupported(f"the element {node.get('name')} without a type")
            ctype = self.complex[_local(type_name)]
        index = len(self.decls)
        self.decls.append(None)
        attributes, anything = self.attributes(ctype)
        particles = []
        for part in ctype:
            tag = _local(part.tag) if not callable(part.tag) else ""
            if tag == "sequence":
                particles += self.sequence(part)
            elif tag in ("choice", "all", "simpleContent", "complexContent", "group"):
                raise Unsupported(f"a complexType's {tag}")
        if ctype.get("mixed") == "true":
            raise Unsupported("mixed content")
        self.decls[index] = (node.get("name"), attributes, anything, particles)
        return index

    def sequence(self, seq):
        """[(names, decl indices, min, max or -1)] of a sequence's particles."""
        out = []
        for part in seq:
            if callable(part.tag):
                continue
            tag = _local(part.tag)
            low, high = int(part.get("minOccurs", "1")), part.get("maxOccurs", "1")
            high = -1 if high == "unbounded" else int(high)
            if tag == "element":
                out.append(((part.get("name"),), (self.element(part),), low, high))
            elif tag == "group":
                choice = self.groups[part.get("ref")].find(f"{XS}choice")
                if choice is None:
                    raise Unsupported("a group that is not one choice")
                members = [e for e in choice if not callable(e.tag) and _local(e.tag) == "element"]
                if len(members) != len([e for e in choice if not callable(e.tag)]):
                    raise Unsupported("a choice of anything but elements")
                out.append((tuple(e.get("name") for e in members), tuple(self.element(e) for e in members), low, high))
            else:
                raise Unsupported(f"a sequence's {tag}")
        return out


@lru_cache(maxsize=None)
def table():
    """The step schema's table: [(element name, [(attribute, kind, required, low, low exclusive,
    high, enumeration, fixed)], any other attribute allowed, [(names, declarations, min, max)])],
    the root <step> first."""
    from lxml import etree
    root = etree.parse(str(schema_path("step"))).getroot()
    compiler = _Compiler(root)
    (step,) = [e for e in root.findall(f"{XS}element") if e.get("name") == "step"]
    compiler.element(step)
    return tuple(compiler.decls)
