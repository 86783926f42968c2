"""Reading a YAML configuration with line numbers: the helpers every section reader uses.

A :class:`Doc` is a composed YAML node with its field path; the readers (``number``,
``string``, ``boolean``, ``fields`` ...) return the typed value or :data:`MISSING` after
recording an error that names ``file:line: path`` (config.py collects them all and raises
one InputErrors). Unknown keys are errors too.
"""

from __future__ import annotations

import reprlib
import sys
from typing import Any, Callable

import yaml

from nurbsmotion.errors import InputError


class Doc:
    """A composed YAML node plus its field path; reads typed values with located errors."""

    def __init__(self, source: str, node: yaml.Node, path: str, errors: list[InputError], lines: dict[str, int]):
        self.source, self.node, self.path, self.errors, self.lines = source, node, path, errors, lines
        lines.setdefault(path, node.start_mark.line + 1)

    def where(self, node: yaml.Node | None = None, path: str | None = None) -> str:
        n = node or self.node
        return f"{self.source}:{n.start_mark.line + 1}: {path if path is not None else self.path}"

    def fail(self, message: str, node: yaml.Node | None = None, path: str | None = None) -> None:
        self.errors.append(InputError(self.where(node, path), message))

    def child_path(self, key: str | int) -> str:
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else key

    def mapping(self, allowed: tuple[str, ...]) -> dict[str, "Doc"]:
        if not isinstance(self.node, yaml.MappingNode):
            self.fail("must be a mapping of key: value")
            return {}
        out: dict[str, Doc] = {}
        for key_node, value_node in self.node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
            if key not in allowed:
                self.fail(f"unknown key {key!r}; expected one of: {', '.join(allowed)}", key_node, self.child_path(str(key)))
            elif key in out:
                self.fail("duplicate key", key_node, self.child_path(key))
            else:
                out[key] = Doc(self.source, value_node, self.child_path(key), self.errors, self.lines)
        return out

    def sequence(self) -> list["Doc"]:
        if not isinstance(self.node, yaml.SequenceNode):
            self.fail("must be a list")
            return []
        return [Doc(self.source, n, self.child_path(i), self.errors, self.lines) for i, n in enumerate(self.node.value)]

    def value(self) -> Any:
        try:
            return yaml.safe_load(yaml.serialize(self.node))
        except (yaml.YAMLError, ValueError, RecursionError) as err:  # '!!int 1.5', nested thousands deep
            self.fail(f"unreadable value ({' '.join(str(err).split())[:200]})")
            return None


MISSING = object()
SHOWN = reprlib.Repr()  # a value in an error message: short even for an alias bomb or a huge list
SHOWN.maxlevel, SHOWN.maxlist, SHOWN.maxdict, SHOWN.maxstring, SHOWN.maxlong = 2, 4, 4, 60, 60


def number(doc: Doc, *, integer: bool = False, minimum: float | None = None, exclusive_min: bool = True,
            maximum: float | None = None) -> Any:
    value = doc.value()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        doc.fail(f"must be {'an integer' if integer else 'a number'}, got {SHOWN.repr(value)}")
        return MISSING
    if not abs(value) <= sys.float_info.max:  # inf, nan, or an integer beyond the float range
        doc.fail(f"must be finite, got {SHOWN.repr(value)}")
        return MISSING
    if minimum is not None and (value <= minimum if exclusive_min else value < minimum):
        doc.fail(f"must be {'>' if exclusive_min else '>='} {minimum:g}, got {SHOWN.repr(value)}")
        return MISSING
    if maximum is not None and value > maximum:
        doc.fail(f"must be <= {maximum:g}, got {SHOWN.repr(value)}")
        return MISSING
    return value


def string(doc: Doc, choices: tuple[str, ...] | None = None) -> Any:
    value = doc.value()
    if not isinstance(value, str) or not value:
        doc.fail(f"must be a non-empty string, got {SHOWN.repr(value)}")
        return MISSING
    if choices is not None and value not in choices:
        doc.fail(f"must be one of {', '.join(choices)}, got {SHOWN.repr(value)}")
        return MISSING
    return value


def boolean(doc: Doc) -> Any:
    value = doc.value()
    if not isinstance(value, bool):
        doc.fail(f"must be true or false, got {SHOWN.repr(value)}")
        return MISSING
    return value


def optional(reader: Callable[..., Any]) -> Callable[..., Any]:
    def read(doc: Doc, **kw: Any) -> Any:
        return None if doc.value() is None else reader(doc, **kw)
    return read


def fields(doc: Doc, readers: dict[str, tuple[Callable[..., Any], dict[str, Any]]],
            required: tuple[str, ...] = ()) -> dict[str, Any]:
    """Read the keys of a mapping with their readers; collect errors; drop failed values."""
    found = doc.mapping(tuple(readers))
    for key in required:
        if key not in found:
            doc.fail(f"missing required key {key!r}")
    out: dict[str, Any] = {}
    for key, sub in found.items():
        reader, kw = readers[key]
        value = reader(sub, **kw)
        if value is not MISSING:
            out[key] = value
    return out


def sequence_of(reader: Callable[[Doc], Any]) -> Callable[[Doc], Any]:
    def read(doc: Doc) -> Any:
        values = tuple(reader(item) for item in doc.sequence())
        return MISSING if MISSING in values else values
    return read
