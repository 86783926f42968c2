"""The coordinate state and tool the daemon keeps between jobs and restarts: DATA_DIR/offsets.json.

What a completed program leaves (``program.coordinates``: work offsets G54-G59.3, the active
system, G92, G28/G30 positions; ``program.tool_at_end``) is the start of the next one, as
LinuxCNC keeps #5161-#5390 in its parameter file. The file is written atomically (temporary
file, fsync, rename), so a crash leaves the old state or the new one, never half of it::

    {"format": 1, "coordinates": {CoordinateState.as_dict()}, "tool_in_spindle": 3}

A file that cannot be read is one error naming the file and the field; the daemon does not
start on it (silently zeroed offsets would put the tool somewhere else).
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from nurbsmotion.errors import InputError
from nurbsmotion.program import CoordinateState, ReadOptions, ToolTable
from nurbsmotion.program.model import SpindleDirection
from nurbsmotion.program.coordinates import SYSTEM_NAMES

STATE_FILE = "offsets.json"
FORMAT = 1
CLEARABLE = (*SYSTEM_NAMES, "G92", "G28", "G30")


@dataclass(frozen=True)
class MachineState:
    coordinates: CoordinateState = field(default_factory=CoordinateState)
    tool_in_spindle: int | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "coordinates": self.coordinates.as_dict(), "tool_in_spindle": self.tool_in_spindle}

    @classmethod
    def from_dict(cls, data: object, where: str) -> "MachineState":
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise InputError(f"{where}: format", f"must be a mapping with format: {FORMAT}, as the daemon writes it")
        unknown = set(data) - {"format", "coordinates", "tool_in_spindle"}
        if unknown:
            raise InputError(f"{where}: {sorted(unknown)[0]}", "unknown key")
        tool = data.get("tool_in_spindle")
        if tool is not None and (isinstance(tool, bool) or not isinstance(tool, int) or tool < 0):
            raise InputError(f"{where}: tool_in_spindle", f"must be a tool number >= 0 or null, got {tool!r}")
        return cls(CoordinateState.from_dict(data.get("coordinates", {}), f"{where}: coordinates"), tool)

    def read_options(self, tool_table: ToolTable | None, block_delete: bool = True,
                     optional_stop: bool = True, spindle_rpm: float = 0.0) -> ReadOptions:
        """What the G-code reader starts from for the next program on this machine;
        ``spindle_rpm``: the spindle's commanded speed now (signed: + M3, - M4; 0 stopped)."""
        direction = SpindleDirection.CW if spindle_rpm > 0 else SpindleDirection.CCW if spindle_rpm < 0 else \
            SpindleDirection.OFF
        return ReadOptions(tool_table=tool_table, coordinates=self.coordinates, tool_in_spindle=self.tool_in_spindle,
                           spindle=direction, spindle_rpm=abs(spindle_rpm),
                           block_delete=block_delete, optional_stop=optional_stop)

    def status(self) -> dict[str, Any]:
        """The status' ``coordinates`` and ``tool``: the active system and its offset, G92, all offsets."""
        c = self.coordinates
        return {"active": c.active_name, "active_offset_mm": list(c.work_offsets_mm[c.active_system - 1]),
                "g92_mm": list(c.g92_mm), "g92_applied": c.g92_applied, "tool": self.tool_in_spindle,
                **{k: v for k, v in c.as_dict().items() if k not in ("active", "g92_mm", "g92_applied")}}


def state_path(data_dir: str | Path) -> Path:
    return Path(data_dir) / STATE_FILE


def load_state(data_dir: str | Path) -> MachineState:
    """The persisted state, or the default (all zero, G54, no tool) when there is no file."""
    path = state_path(data_dir)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return MachineState()
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(str(path), f"cannot read the persisted offsets: {getattr(err, 'strerror', None) or err}") from None
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError, ValueError) as err:
        line = getattr(err, "lineno", 1)
        raise InputError(f"{path}:{line}", f"not valid JSON ({getattr(err, 'msg', err)}); fix or remove the file "
                                           f"(the offsets are then all zero)") from None
    return MachineState.from_dict(data, str(path))


def save_state(data_dir: str | Path, state: MachineState) -> None:
    """Write the state atomically (OSError if the data directory is not writable)."""
    path = state_path(data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".offsets-", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(state.as_dict(), f, indent=2)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def system_number(name: str, where: str) -> int:
    """'G55' -> 2 (1 = G54 ... 9 = G59.3); InputError naming ``where`` otherwise."""
    canonical = name.strip().upper()
    if canonical not in SYSTEM_NAMES:
        raise InputError(where, f"must be one of {' '.join(SYSTEM_NAMES)}, got {name!r}")
    return SYSTEM_NAMES.index(canonical) + 1


def with_offset(state: MachineState, system: str, xyz_mm: tuple[float | None, float | None, float | None]) -> MachineState:
    """``offsets G55 X10 Y-5``: as G10 L2 P2 X10 Y-5 (axes not given keep their value)."""
    number = system_number(system, "field 'system'")
    old = state.coordinates.work_offsets_mm[number - 1]
    new = tuple(o if v is None else float(v) for o, v in zip(old, xyz_mm))
    return MachineState(state.coordinates.with_work_offset(number, new), state.tool_in_spindle)  # type: ignore[arg-type]


def cleared(state: MachineState, name: str) -> MachineState:
    """``offsets --clear G92`` (as G92.1), ``--clear G55`` (that offset to zero), ``--clear G28``/``G30``."""
    canonical = name.strip().upper()
    c = state.coordinates
    if canonical == "G92":
        c = replace(c, g92_mm=(0.0, 0.0, 0.0), g92_applied=False)
    elif canonical == "G28":
        c = replace(c, g28_mm=(0.0, 0.0, 0.0))
    elif canonical == "G30":
        c = replace(c, g30_mm=(0.0, 0.0, 0.0))
    elif canonical in SYSTEM_NAMES:
        c = c.with_work_offset(SYSTEM_NAMES.index(canonical) + 1, (0.0, 0.0, 0.0))
    else:
        raise InputError("field 'clear'", f"must be one of {' '.join(CLEARABLE)}, got {name!r}")
    return MachineState(c, state.tool_in_spindle)


def selected(state: MachineState, system: str) -> MachineState:
    """``offsets --select G55``: the active coordinate system for the next program (as G55)."""
    return MachineState(replace(state.coordinates, active_system=system_number(system, "field 'select'")),
                        state.tool_in_spindle)
