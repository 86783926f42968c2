"""The tool table: per tool number its length and diameter (mm), read from YAML.

::

    tools:
      - number: 1
        length_mm: 52.3      # G43 H1 adds this to Z (LinuxCNC tool length offset)
        diameter_mm: 6.0
        name: 6 mm flat end  # optional
      - number: 2
        length_mm: 47.15
        diameter_mm: 3.175

Every problem is reported together, each as ``file:line: tools[i].field``. Tool 0 is "no
tool" (length 0) and cannot be listed. G-code uses the table for T (the tool must be in it),
M6 and G43 H (LinuxCNC "Tool Length Offsets", G43: ``H`` selects the table entry).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from nurbsmotion.errors import InputError, InputErrors

TOOL_KEYS = ("number", "length_mm", "diameter_mm", "name")
MAX_TOOL_NUMBER = 99999


@dataclass(frozen=True)
class Tool:
    number: int
    length_mm: float
    diameter_mm: float
    name: str = ""


@dataclass(frozen=True)
class ToolTable:
    tools: dict[int, Tool]
    source: str = "<tool table>"

    def get(self, number: int) -> Tool | None:
        return self.tools.get(number)

    def length_mm(self, number: int) -> float:
        """Length of a tool; tool 0 (no tool) has length 0. KeyError if unknown."""
        if number == 0:
            return 0.0
        return self.tools[number].length_mm


def _scalar(node: yaml.Node) -> Any:
    try:
        return yaml.safe_load(yaml.serialize(node))
    except (yaml.YAMLError, ValueError, RecursionError):
        return None


def _read_tool(node: yaml.Node, path: str, where: Any, errors: list[InputError]) -> Tool | None:
    if not isinstance(node, yaml.MappingNode):
        errors.append(InputError(where(node, path), "a tool is a mapping: number, length_mm, diameter_mm, name"))
        return None
    values: dict[str, Any] = {}
    for key_node, value_node in node.value:
        key = key_node.value
        if key not in TOOL_KEYS or key in values:
            problem = "duplicate key" if key in values else f"unknown key {key!r}; expected one of: {', '.join(TOOL_KEYS)}"
            errors.append(InputError(where(key_node, f"{path}.{key}"), problem))
            continue
        value = _scalar(value_node)
        if key == "name":
            values[key] = str(value)
        elif key == "number":
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_TOOL_NUMBER:
                errors.append(InputError(where(value_node, f"{path}.number"), f"must be an integer from 1 to {MAX_TOOL_NUMBER}, got {value!r}"))
                return None
            values[key] = value
        else:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            if not ok or (key == "diameter_mm" and value < 0):
                errors.append(InputError(where(value_node, f"{path}.{key}"), f"must be a finite number{' >= 0' if key == 'diameter_mm' else ''}, got {value!r}"))
                return None
            values[key] = float(value)
    missing = [k for k in ("number", "length_mm", "diameter_mm") if k not in values]
    if missing:
        errors.append(InputError(where(node, path), f"missing {', '.join(missing)}"))
        return None
    return Tool(values["number"], values["length_mm"], values["diameter_mm"], values.get("name", ""))


def parse_tool_table(text: str, source: str = "<tool table>") -> ToolTable:
    """Read a tool table; InputErrors listing every problem."""
    def where(node: yaml.Node, path: str) -> str:
        return f"{source}:{node.start_mark.line + 1}: {path}"

    try:
        root = yaml.compose(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        raise InputError(f"{source}:{mark.line + 1 if mark else 1}", f"YAML syntax error: {getattr(err, 'problem', err)}") from None
    top = {k.value: v for k, v in root.value} if isinstance(root, yaml.MappingNode) else {}
    if set(top) != {"tools"} or not isinstance(top["tools"], yaml.SequenceNode):
        raise InputError(f"{source}:1", "a tool table is a mapping with one key, tools: a list of tools")
    errors: list[InputError] = []
    tools: dict[int, Tool] = {}
    for i, node in enumerate(top["tools"].value):
        tool = _read_tool(node, f"tools[{i}]", where, errors)
        if tool is not None and tool.number in tools:
            errors.append(InputError(where(node, f"tools[{i}].number"), f"tool {tool.number} is listed twice"))
        elif tool is not None:
            tools[tool.number] = tool
    if errors:
        raise InputErrors(errors)
    return ToolTable(tools, source)


def load_tool_table(path: str | Path) -> ToolTable:
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as err:
        raise InputError(str(path), f"cannot read tool table: {err.strerror or err}") from None
    return parse_tool_table(text, str(path))
