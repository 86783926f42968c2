"""The ``io:`` section: one CiA-401 digital I/O node with named inputs and outputs by bit.

```yaml
io:
  node_id: 10
  inputs:                      # 0x6000 sub 1.. (8 bits each): bit n = sub n//8 + 1, bit n%8
    estop: {bit: 0, active_low: true}    # normally closed: a broken wire reads as pressed
    limit_x_min: 1
    x_neg_switch: {bit: 2, active_low: true, limit: X-}  # any name: the switch at X's negative end
  outputs:                     # 0x6200 sub 1..
    coolant_flood: 0
    coolant_mist: 1
```

A signal is ``name: bit`` or ``name: {bit: N, active_low: BOOL, limit: AXIS}``; an input
named ``limit_<axis>[_min|_max]`` or with ``limit: AXIS`` is a limit switch of that axis (the
daemon aborts that axis' job when it becomes active, service.machine_io); ``limit: X-`` /
``limit: X+`` (and the names' ``_min`` / ``_max``) say which end, so a jog can move the axis
off it (away from that end); bits 0..63 (eight 8-bit
groups, what one PDO carries). Names are identifiers; a bit is used by one name only.
config.py calls :func:`read_io` for ``io`` and :func:`check_io_node` across sections.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import yaml

from nurbsmotion.config.yaml_reading import Doc, MISSING, SHOWN, boolean, fields, number, string

MAX_BITS = 64  # eight UNSIGNED8 groups: one 8-byte PDO
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class IoSignal:
    """One named digital signal: bit ``bit`` of the node's 8-bit groups (group bit//8)."""

    name: str
    bit: int
    active_low: bool = False
    limit: str | None = None  # the axis whose limit switch this input is (``limit: X``, ``X-``, ``X+``)

    @property
    def group(self) -> int:
        """0-based 8-bit group; the object sub-index is group + 1."""
        return self.bit // 8


@dataclass(frozen=True)
class IoConfig:
    node_id: int
    inputs: tuple[IoSignal, ...] = ()
    outputs: tuple[IoSignal, ...] = ()

    def groups(self, signals: tuple[IoSignal, ...]) -> int:
        """Number of 8-bit groups that hold ``signals`` (0 if none)."""
        return max((s.group + 1 for s in signals), default=0)

    @property
    def input_groups(self) -> int:
        return self.groups(self.inputs)

    @property
    def output_groups(self) -> int:
        return self.groups(self.outputs)


_BIT: tuple[Callable[..., Any], dict[str, Any]] = (number, {"integer": True, "minimum": 0, "exclusive_min": False, "maximum": MAX_BITS - 1})


def _signal(name: str, doc: Doc) -> Any:
    if isinstance(doc.node, yaml.MappingNode):
        values = fields(doc, {"bit": _BIT, "active_low": (boolean, {}), "limit": (string, {})}, required=("bit",))
        return IoSignal(name, **values) if "bit" in values else MISSING
    bit = _BIT[0](doc, **_BIT[1])
    return MISSING if bit is MISSING else IoSignal(name, bit)


def _signals(doc: Doc) -> Any:
    """``{name: bit | {bit, active_low}}`` -> tuple of IoSignal; names and bits unique."""
    if doc.value() is None:
        return ()
    if not isinstance(doc.node, yaml.MappingNode):
        doc.fail("must be a mapping of name: bit")
        return MISSING
    signals: list[IoSignal] = []
    names: set[str] = set()
    bits: dict[int, str] = {}
    for key_node, value_node in doc.node.value:
        name = key_node.value if isinstance(key_node, yaml.ScalarNode) else ""
        path = doc.child_path(str(name))
        sub = Doc(doc.source, value_node, path, doc.errors, doc.lines)
        if not _NAME.match(name):
            doc.fail(f"signal name {SHOWN.repr(name)} must be an identifier (letters, digits, _)", key_node, path)
            continue
        if name in names:
            doc.fail("duplicate signal name", key_node, path)
            continue
        names.add(name)
        signal = _signal(name, sub)
        if signal is MISSING:
            continue
        if signal.bit in bits:
            sub.fail(f"bit {signal.bit} is already used by {bits[signal.bit]!r}")
            continue
        bits[signal.bit] = name
        signals.append(signal)
    return tuple(signals)


_READERS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {
    "node_id": (number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 127}),
    "inputs": (_signals, {}),
    "outputs": (_signals, {}),
}


def read_io(doc: Doc) -> Any:
    """``io`` -> IoConfig (or MISSING after recording located errors)."""
    before = len(doc.errors)
    values = fields(doc, _READERS, required=("node_id",))
    if len(doc.errors) > before or "node_id" not in values:
        return MISSING
    return IoConfig(**values)


def check_io_node(io: IoConfig | None, axis_node_ids: tuple[int, ...], fail: Callable[[str, str], None]) -> None:
    """The I/O node's id must differ from every axis' node id (one id, one device)."""
    if io is not None and io.node_id in axis_node_ids:
        fail("io.node_id", f"node id {io.node_id} is already used by an axis")


def limit_axis_side(limit: str) -> tuple[str, int]:
    """``limit: X-`` -> ("X", -1) (the switch at the axis' negative end), ``X+`` -> ("X", +1),
    ``X`` -> ("X", 0): the end is not said."""
    if limit.endswith(("+", "-")):
        return limit[:-1], 1 if limit.endswith("+") else -1
    return limit, 0


def check_io_limits(io: IoConfig | None, axis_names: tuple[str, ...], fail: Callable[[str, str], None]) -> None:
    """``limit: AXIS`` (or ``AXIS-`` / ``AXIS+``) names a configured axis, and only on an input."""
    if io is None:
        return
    for kind, signals in (("inputs", io.inputs), ("outputs", io.outputs)):
        for s in signals:
            if s.limit is None:
                continue
            if kind == "outputs":
                fail(f"io.outputs.{s.name}.limit", "an output is no limit switch: limit is for inputs")
            elif limit_axis_side(s.limit)[0] not in axis_names:
                fail(f"io.inputs.{s.name}.limit", f"no axis {limit_axis_side(s.limit)[0]!r} (axes: "
                     f"{', '.join(axis_names)}; X- / X+ name its negative / positive end)")
