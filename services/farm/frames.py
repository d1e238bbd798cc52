"""Frames: a job's scene changed by one JSON Patch (RFC 6902) per frame.

A job may carry ``frames``, a list whose i-th entry is a JSON Patch, a list of operations
(``add``, ``remove``, ``replace``, ``move``, ``copy``, ``test``), applied to the job's scene to
make frame i: a camera path, a moving object, a material sweep. ``apply_patch`` is strict where
RFC 6902 is: every operation names a path that exists (``add`` its parent; ``-`` appends to an
array), array indices are decimal without leading zeros, ``test`` compares JSON values (``1`` is
not ``true``), and a patch that fails leaves nothing half-applied (it works on a copy). Paths are
JSON Pointers (RFC 6901: ``/materials/wax/density``, ``~1`` for ``/`` and ``~0`` for ``~``).

``sweep_patches("materials.wax.density", [1, 2, 4, 8])`` makes one ``replace`` a frame (what
``lucent submit --sweep`` sends).
"""

from __future__ import annotations

import copy
import json
from typing import Any

OPS = ("add", "remove", "replace", "move", "copy", "test")


class PatchError(ValueError):
    """A patch that cannot apply: which operation (its index in the patch), the field of the
    operation at fault (``path``, ``from``, ``op``, ``value``) and why."""

    def __init__(self, index: int, field: str, message: str):
        super().__init__(message)
        self.index = index
        self.field = field
        self.message = message


def _tokens(pointer: Any, index: int, field: str) -> list[str]:
    if not isinstance(pointer, str):
        raise PatchError(index, field, f"'{field}' must be a JSON Pointer string")
    if pointer == "":
        return []
    if not pointer.startswith("/"):
        raise PatchError(index, field, f"{pointer!r} is not a JSON Pointer (it starts with '/')")
    return [t.replace("~1", "/").replace("~0", "~") for t in pointer[1:].split("/")]


def _array_index(token: str, length: int, index: int, field: str, pointer: str,
                 append: bool) -> int:
    if append and token == "-":
        return length
    if not token.isdigit() or (len(token) > 1 and token[0] == "0"):
        raise PatchError(index, field, f"path {pointer} does not exist: {token!r} is not an "
                                       "array index")
    i = int(token)
    if i > length or (i == length and not append):
        raise PatchError(index, field, f"path {pointer} does not exist: index {i} is past the "
                                       f"end of an array of {length}")
    return i


def _parent(doc: Any, tokens: list[str], index: int, field: str, pointer: str) -> Any:
    """The container that holds the pointer's last token."""
    node = doc
    for depth, token in enumerate(tokens[:-1]):
        if isinstance(node, dict):
            if token not in node:
                raise PatchError(index, field, f"path {pointer} does not exist: no "
                                               f"{'/' + '/'.join(tokens[:depth + 1])}")
            node = node[token]
        elif isinstance(node, list):
            node = node[_array_index(token, len(node), index, field, pointer, False)]
        else:
            raise PatchError(index, field, f"path {pointer} does not exist: "
                                           f"{'/' + '/'.join(tokens[:depth])} is not an object "
                                           "or array")
    if not isinstance(node, (dict, list)):
        raise PatchError(index, field, f"path {pointer} does not exist: its parent is not an "
                                       "object or array")
    return node


def _locate(doc: Any, tokens: list[str], index: int, field: str,
            pointer: str) -> tuple[Any, Any]:
    """The container of an existing value and its key (a member name or an array index)."""
    parent = _parent(doc, tokens, index, field, pointer)
    last = tokens[-1]
    if isinstance(parent, dict):
        if last not in parent:
            raise PatchError(index, field, f"path {pointer} does not exist")
        return parent, last
    return parent, _array_index(last, len(parent), index, field, pointer, False)


def _get(doc: Any, pointer: str, index: int, field: str) -> Any:
    tokens = _tokens(pointer, index, field)
    if not tokens:
        return doc
    parent, key = _locate(doc, tokens, index, field, pointer)
    return parent[key]


def _remove(doc: Any, pointer: str, index: int, field: str) -> Any:
    tokens = _tokens(pointer, index, field)
    if not tokens:
        raise PatchError(index, field, "cannot remove the whole document")
    parent, key = _locate(doc, tokens, index, field, pointer)
    return parent.pop(key)


def _add(doc: Any, pointer: str, value: Any, index: int, field: str) -> Any:
    """The document with ``value`` added at ``pointer`` (the root replaced when it is '')."""
    tokens = _tokens(pointer, index, field)
    if not tokens:
        return value
    parent = _parent(doc, tokens, index, field, pointer)
    last = tokens[-1]
    if isinstance(parent, dict):
        parent[last] = value
    else:
        parent.insert(_array_index(last, len(parent), index, field, pointer, True), value)
    return doc


def _json_equal(a: Any, b: Any) -> bool:
    """RFC 6902 §4.6 equality: ``1`` and ``1.0`` are equal, ``1`` and ``true`` are not."""
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return a == b
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_json_equal(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_json_equal(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def apply_patch(doc: Any, patch: Any) -> Any:
    """``doc`` with the JSON Patch ``patch`` applied, as a new document (``doc`` unchanged);
    ``PatchError`` naming the operation at fault otherwise."""
    if not isinstance(patch, list):
        raise PatchError(-1, "", "a frame is a JSON Patch: a list of operations")
    out = copy.deepcopy(doc)
    for i, op in enumerate(patch):
        if not isinstance(op, dict):
            raise PatchError(i, "", "an operation is an object with 'op' and 'path'")
        name = op.get("op")
        if name not in OPS:
            raise PatchError(i, "op", f"'op' must be one of {', '.join(OPS)} (got {name!r})")
        allowed = {"op", "path"} | ({"value"} if name in ("add", "replace", "test") else set()) \
            | ({"from"} if name in ("move", "copy") else set())
        for key in op:
            if key not in allowed:
                raise PatchError(i, str(key), f"unknown member {key!r} of a {name!r} operation")
        if "path" not in op:
            raise PatchError(i, "path", "'path' is required")
        path = op["path"]
        if name in ("add", "replace", "test") and "value" not in op:
            raise PatchError(i, "value", f"'value' is required by {name!r}")
        if name in ("move", "copy") and "from" not in op:
            raise PatchError(i, "from", f"'from' is required by {name!r}")
        if name == "add":
            out = _add(out, path, copy.deepcopy(op["value"]), i, "path")
        elif name == "remove":
            _remove(out, path, i, "path")
        elif name == "replace":
            _get(out, path, i, "path")  # must exist
            tokens = _tokens(path, i, "path")
            if tokens:
                _remove(out, path, i, "path")
            out = _add(out, path, copy.deepcopy(op["value"]), i, "path")
        elif name == "move":
            source = op["from"]
            if isinstance(path, str) and isinstance(source, str) and \
                    path.startswith(source + "/"):
                raise PatchError(i, "from", f"cannot move {source} into its own child {path}")
            value = _remove(out, source, i, "from") if source != path else None
            if source != path:
                out = _add(out, path, value, i, "path")
        elif name == "copy":
            out = _add(out, path, copy.deepcopy(_get(out, op["from"], i, "from")), i, "path")
        else:  # test
            if not _json_equal(_get(out, path, i, "path"), op["value"]):
                raise PatchError(i, "value", f"test failed: {path} is not "
                                             f"{json.dumps(op['value'])[:80]}")
    return out


def pointer(dotted: str) -> str:
    """``materials.wax.density`` (or ``objects.0.radius``) -> ``/materials/wax/density``."""
    return "".join("/" + part.replace("~", "~0").replace("/", "~1")
                   for part in dotted.split("."))


def sweep_patches(dotted: str, values: list[Any]) -> list[list[dict[str, Any]]]:
    """One frame a value: ``replace`` of the field ``dotted`` names."""
    return [[{"op": "replace", "path": pointer(dotted), "value": v}] for v in values]
