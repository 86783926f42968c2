"""YAML curve files -> Program of NURBS blocks; every problem named by file:line and field.

One curve::

    name: wang_table1          # optional
    degree: 2
    points: [[0, 0, 0], [-50, 80, 80], ...]   # [x, y] points get z = 0
    weights: [1, 25, ...]      # optional, default 1
    knots: [0, 0, 0, ...]      # optional, default clamped uniform on [0, 1]
    feed_mm_min: 12000         # optional, default: the machine's feed

or several under ``curves:`` (each as above; a top-level ``feed_mm_min`` is the default of
the curves without one). Each curve must start where the previous one ends. The program
starts at the first point of the first curve. All problems are reported together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.geometry import clamped_uniform_knots
from nurbsmotion.program.curve_check import CurveProblem, build_curve
from nurbsmotion.program.model import Block, BlockKind, Program, SourceRef

CURVE_KEYS = ("name", "degree", "points", "weights", "knots", "feed_mm_min")
PROGRAM_KEYS = ("name", "feed_mm_min", "curves")
MAX_DEGREE = 9
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml when available: same nodes and marks, faster
JOIN_TOLERANCE_MM = 1e-6


@dataclass
class _Reader:
    """Typed reads of composed YAML nodes; problems are collected, not raised."""

    source: str
    errors: list[InputError] = field(default_factory=list)
    loader: Any = None

    def where(self, node: yaml.Node, path: str) -> str:
        return f"{self.source}:{node.start_mark.line + 1}: {path}" if path else f"{self.source}:{node.start_mark.line + 1}"

    def fail(self, node: yaml.Node, path: str, message: str) -> None:
        self.errors.append(InputError(self.where(node, path), message))

    def value(self, node: yaml.Node) -> Any:
        if self.loader is None:
            self.loader = yaml.SafeLoader("")
        try:
            return self.loader.construct_object(node, deep=True)
        except (yaml.YAMLError, ValueError, TypeError, OverflowError) as err:
            return f"<unreadable: {type(err).__name__}>"

    def mapping(self, node: yaml.Node, path: str, allowed: tuple[str, ...]) -> dict[str, tuple[yaml.Node, yaml.Node]]:
        if not isinstance(node, yaml.MappingNode):
            self.fail(node, path, f"must be a mapping with keys {', '.join(allowed)}")
            return {}
        out: dict[str, tuple[yaml.Node, yaml.Node]] = {}
        for key_node, value_node in node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
            child = f"{path}.{key}" if path else str(key)
            if key not in allowed:
                self.fail(key_node, child, f"unknown key {key!r}; expected one of: {', '.join(allowed)}")
            elif key in out:
                self.fail(key_node, child, "duplicate key")
            else:
                out[key] = (key_node, value_node)
        return out

    def number(self, node: yaml.Node, path: str, *, integer: bool = False, positive: bool = False) -> float | None:
        v = self.value(node) if isinstance(node, yaml.ScalarNode) else None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
            shown = v if isinstance(node, yaml.ScalarNode) else "a list or mapping"
            self.fail(node, path, f"must be {'an integer' if integer else 'a number'}, got {shown!r}")
            return None
        if not math.isfinite(v):
            self.fail(node, path, f"must be a finite number, got {v!r}")
            return None
        if positive and v <= 0:
            self.fail(node, path, f"must be > 0, got {v!r}")
            return None
        return v

    def sequence(self, node: yaml.Node, path: str) -> list[yaml.Node] | None:
        if not isinstance(node, yaml.SequenceNode):
            self.fail(node, path, "must be a list")
            return None
        if not node.value:
            self.fail(node, path, "must not be empty")
            return None
        return list(node.value)

    def numbers(self, node: yaml.Node, path: str) -> list[float] | None:
        items = self.sequence(node, path)
        if items is None:
            return None
        values = [self.number(n, f"{path}[{i}]") for i, n in enumerate(items)]
        return None if any(v is None for v in values) else [float(v) for v in values]  # type: ignore[arg-type]

    def points(self, node: yaml.Node, path: str) -> list[list[float]] | None:
        items = self.sequence(node, path)
        if items is None:
            return None
        out: list[list[float]] = []
        for i, item in enumerate(items):
            p = self.numbers(item, f"{path}[{i}]")
            if p is not None and len(p) not in (2, 3):
                self.fail(item, f"{path}[{i}]", f"a point is [x, y] or [x, y, z], got {len(p)} numbers")
                p = None
            if p is not None:
                out.append(p + [0.0] * (3 - len(p)))
        return out if len(out) == len(items) else None


@dataclass
class _Curve:
    block: Block | None
    path: str
    first_point_node: yaml.Node | None


def _read_curve(r: _Reader, node: yaml.Node, path: str, default_feed_mm_min: float | None) -> _Curve:
    fields = r.mapping(node, path, CURVE_KEYS)
    prefix = f"{path}." if path else ""
    errors_before = len(r.errors)
    for required in ("degree", "points"):
        if isinstance(node, yaml.MappingNode) and required not in fields:
            r.fail(node, f"{prefix}{required}", "missing (required)")
    got = {k: v for k, (_, v) in fields.items()}
    degree = r.number(got["degree"], f"{prefix}degree", integer=True) if "degree" in got else None
    points = r.points(got["points"], f"{prefix}points") if "points" in got else None
    weights = r.numbers(got["weights"], f"{prefix}weights") if "weights" in got else None
    knots = r.numbers(got["knots"], f"{prefix}knots") if "knots" in got else None
    feed = r.number(got["feed_mm_min"], f"{prefix}feed_mm_min", positive=True) if "feed_mm_min" in got else default_feed_mm_min
    if "name" in got and not isinstance(r.value(got["name"]), str):
        r.fail(got["name"], f"{prefix}name", "must be a string")
    first_node = got["points"].value[0] if points else None
    if len(r.errors) > errors_before or degree is None or points is None:
        return _Curve(None, path, first_node)
    n, d = len(points), int(degree)
    if weights is None:
        weights = [1.0] * n
    if knots is None:
        knots = list(clamped_uniform_knots(n, d)) if 1 <= d < n else []

    def locate(problem: CurveProblem) -> str:
        key = {"control_points": "points"}.get(problem.field, problem.field)
        if key not in got:
            return r.where(got.get("points", node) if key != "degree" else node, f"{prefix}{key}")
        key_node, value_node = fields[key]
        if problem.index is not None and isinstance(value_node, yaml.SequenceNode) and problem.index < len(value_node.value):
            return r.where(value_node.value[problem.index], f"{prefix}{key}[{problem.index}]")
        return r.where(key_node, f"{prefix}{key}")

    try:
        curve = build_curve(d, points, weights, knots, locate, max_degree=MAX_DEGREE, zero_length_mm=JOIN_TOLERANCE_MM)
    except InputErrors as errs:
        r.errors.extend(errs.errors)
        return _Curve(None, path, first_node)
    line = node.start_mark.line + 1
    name = r.value(got["name"]) if "name" in got else (path or "curve")
    source = SourceRef(r.source, line, f"{name}: degree {d}, {n} control points")
    return _Curve(Block(BlockKind.NURBS, curve, None if feed is None else feed / 60.0, source), path, first_node)


def parse_curve_yaml(text: str, source: str = "<yaml>") -> Program:
    """Parse a YAML curve file (module docstring) into a Program of NURBS blocks."""
    r = _Reader(source)
    try:
        root = yaml.compose(text, Loader=_LOADER)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
        line = mark.line + 1 if mark is not None else 1
        problem = " ".join(str(getattr(err, "problem", None) or err).split())
        raise InputError(f"{source}:{line}", f"YAML syntax error: {problem}") from None
    if root is None:
        raise InputError(f"{source}:1", "empty curve file: expected degree and points (or curves:)")
    has_curves = isinstance(root, yaml.MappingNode) and any(
        isinstance(k, yaml.ScalarNode) and k.value == "curves" for k, _ in root.value)
    name = Path(source).stem or source
    if has_curves:
        top = r.mapping(root, "", PROGRAM_KEYS)
        default_feed = r.number(top["feed_mm_min"][1], "feed_mm_min", positive=True) if "feed_mm_min" in top else None
        items = r.sequence(top["curves"][1], "curves") or []
        curves = [_read_curve(r, n, f"curves[{i}]", default_feed) for i, n in enumerate(items)]
        name_node = top.get("name")
    else:
        curves = [_read_curve(r, root, "", None)]
        name_node = dict((k.value, (k, v)) for k, v in root.value).get("name") if isinstance(root, yaml.MappingNode) else None
    if name_node is not None and isinstance(r.value(name_node[1]), str):
        name = r.value(name_node[1])
    _check_joins(r, curves)
    if r.errors:
        raise InputErrors(r.errors)
    blocks = tuple(c.block for c in curves if c.block is not None)
    return Program(str(name), blocks, blocks[0].start.copy())


def _check_joins(r: _Reader, curves: list[_Curve]) -> None:
    """Each curve must start where the previous one ends (no implicit connecting moves)."""
    for prev, cur in zip(curves, curves[1:]):
        if prev.block is None or cur.block is None or cur.first_point_node is None:
            continue
        gap = float(np.linalg.norm(cur.block.start - prev.block.end))
        if gap > JOIN_TOLERANCE_MM:
            r.fail(cur.first_point_node, f"{cur.path}.points[0]",
                   f"does not start where {prev.path} ends ({', '.join(f'{v:g}' for v in prev.block.end)}); gap {gap:.6g} mm")
