"""JSON that dc reads back (manifests, records, journals, lock notes, metadata, kept units, a
contestant's answers): one parser whose every refusal is a ValueError, so that each reader's own
handler names its file. A document nested deeper than Python's parser recurses was a
RecursionError that no reader caught (the catch-all's "nested too deeply", naming nothing); one
nested deeper than anything dc writes is refused too, before code that walks it recurses."""
import json

# dc's deepest document nests a few levels (a manifest: object, list, record, list); a study's
# kept unit, the rows of a study, a few more. Far beyond both, far below Python's recursion limit.
MAX_DEPTH = 64


def loads(data, **kwargs):
    """json.loads(data, **kwargs); ValueError for a document nested deeper than MAX_DEPTH levels
    (or than the parser goes), as for any other that is not JSON."""
    try:
        value = json.loads(data, **kwargs)
    except RecursionError:
        raise ValueError(f"it is nested deeper than {MAX_DEPTH} levels (dc writes none so deep)") from None
    if deeper(value, MAX_DEPTH):
        raise ValueError(f"it is nested deeper than {MAX_DEPTH} levels (dc writes none so deep)")
    return value


def deeper(value, limit):
    """Whether value (parsed JSON) nests lists and objects more than `limit` deep; walked with a
    stack of its own, not by recursion."""
    stack = [(value, 1)]
    while stack:
        v, depth = stack.pop()
        items = v.values() if isinstance(v, dict) else v if isinstance(v, list) else ()
        for item in items:
            if isinstance(item, (dict, list)):
                if depth >= limit:
                    return True
                stack.append((item, depth + 1))
    return False
