"""Coordinate systems: work offsets G54-G59.3, G92 offsets, G28/G30 positions (machine mm).

LinuxCNC "Coordinate Systems" and "G-codes" G10 L2/L20, G28, G30, G53, G54-G59.3, G92:

    machine = program + work_offset[active] + (g92 if g92_applied) + tool length (Z)

All values are machine millimetres. ``CoordinateState`` is what a reader starts from and
what a Program ends with: the service persists it between jobs and restarts (``as_dict`` /
``from_dict``, JSON-ready; LinuxCNC
keeps the same values in its parameter file, #5161-#5390). ``parameter`` maps the LinuxCNC
parameter numbers onto it so programs can read them (``#5221`` = G54 X offset, ...).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError

SYSTEM_NAMES = ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")
Triple = tuple[float, float, float]
ZERO: Triple = (0.0, 0.0, 0.0)

G28_PARAM, G30_PARAM, G92_FLAG_PARAM, G92_PARAM, ACTIVE_PARAM, WORK_PARAM = 5161, 5181, 5210, 5211, 5220, 5221
WORK_PARAM_STRIDE = 20  # #5221 G54 X, #5241 G55 X, ... (LinuxCNC parameter table)


def _triple(v: NDArray[np.float64] | Triple) -> Triple:
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class CoordinateState:
    """Offsets in effect: work offsets of systems 1-9 (G54-G59.3), the active one, G92, G28/G30."""

    work_offsets_mm: tuple[Triple, ...] = (ZERO,) * 9
    active_system: int = 1  # 1 = G54 ... 9 = G59.3
    g92_mm: Triple = ZERO
    g92_applied: bool = False
    g28_mm: Triple = ZERO
    g30_mm: Triple = ZERO

    def __post_init__(self) -> None:
        if len(self.work_offsets_mm) != 9 or not 1 <= self.active_system <= 9:
            raise ValueError("CoordinateState needs 9 work offsets and an active system 1..9")
        for v in (*self.work_offsets_mm, self.g92_mm, self.g28_mm, self.g30_mm):
            if len(v) != 3 or not np.all(np.isfinite(v)):
                raise ValueError(f"coordinate values must be 3 finite numbers, got {v!r}")

    @property
    def active_name(self) -> str:
        return SYSTEM_NAMES[self.active_system - 1]

    def as_dict(self) -> dict[str, object]:
        return {"active": self.active_name,
                "work_offsets_mm": {name: list(v) for name, v in zip(SYSTEM_NAMES, self.work_offsets_mm)},
                "g92_mm": list(self.g92_mm), "g92_applied": self.g92_applied,
                "g28_mm": list(self.g28_mm), "g30_mm": list(self.g30_mm)}

    @classmethod
    def from_dict(cls, data: object, where: str = "offsets") -> "CoordinateState":
        """The inverse of ``as_dict`` (a persisted state); InputError naming the bad field."""
        if not isinstance(data, dict):
            raise InputError(where, "must be a mapping as written by CoordinateState.as_dict")

        def triple(value: object, field_name: str) -> Triple:
            ok = isinstance(value, (list, tuple)) and len(value) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)
            if not ok:
                raise InputError(f"{where}.{field_name}", f"must be 3 finite numbers [x, y, z] in mm, got {value!r}")
            return _triple(value)  # type: ignore[arg-type]

        unknown = set(data) - {"active", "work_offsets_mm", "g92_mm", "g92_applied", "g28_mm", "g30_mm"}
        if unknown:
            raise InputError(f"{where}.{sorted(unknown)[0]}", "unknown key")
        active = data.get("active", "G54")
        if active not in SYSTEM_NAMES:
            raise InputError(f"{where}.active", f"must be one of {' '.join(SYSTEM_NAMES)}, got {active!r}")
        work = data.get("work_offsets_mm", {})
        if not isinstance(work, dict) or set(work) - set(SYSTEM_NAMES):
            raise InputError(f"{where}.work_offsets_mm", f"must map {' '.join(SYSTEM_NAMES)} to [x, y, z]")
        applied = data.get("g92_applied", False)
        if not isinstance(applied, bool):
            raise InputError(f"{where}.g92_applied", f"must be true or false, got {applied!r}")
        return cls(tuple(triple(work.get(n, ZERO), f"work_offsets_mm.{n}") for n in SYSTEM_NAMES),
                   SYSTEM_NAMES.index(active) + 1, triple(data.get("g92_mm", ZERO), "g92_mm"), applied,
                   triple(data.get("g28_mm", ZERO), "g28_mm"), triple(data.get("g30_mm", ZERO), "g30_mm"))

    def with_work_offset(self, system: int, offset_mm: Triple) -> "CoordinateState":
        offsets = list(self.work_offsets_mm)
        offsets[system - 1] = _triple(offset_mm)
        return replace(self, work_offsets_mm=tuple(offsets))


@dataclass
class Offsets:
    """The reader's mutable copy of a CoordinateState, plus the tool length offset."""

    work: list[NDArray[np.float64]]
    active: int
    g92: NDArray[np.float64]
    g92_applied: bool
    g28: NDArray[np.float64]
    g30: NDArray[np.float64]
    tool_length_mm: float = 0.0
    machine_mode: bool = field(default=False)  # G53 on this block: no offsets

    @classmethod
    def from_state(cls, s: CoordinateState) -> "Offsets":
        return cls([np.array(v, float) for v in s.work_offsets_mm], s.active_system, np.array(s.g92_mm, float),
                   s.g92_applied, np.array(s.g28_mm, float), np.array(s.g30_mm, float))

    def state(self) -> CoordinateState:
        return CoordinateState(tuple(_triple(v) for v in self.work), self.active, _triple(self.g92), self.g92_applied,
                               _triple(self.g28), _triple(self.g30))

    def total(self, with_tool: bool = True) -> NDArray[np.float64]:
        """machine - program (mm) for each axis."""
        if self.machine_mode:
            return np.zeros(3)
        total = self.work[self.active - 1] + (self.g92 if self.g92_applied else 0.0)
        if with_tool:
            total = total + np.array([0.0, 0.0, self.tool_length_mm])
        return total

    def parameter(self, number: int) -> float | None:
        """LinuxCNC's numbered parameter for this state, or None if ``number`` is not one."""
        for base, v in ((G28_PARAM, self.g28), (G30_PARAM, self.g30), (G92_PARAM, self.g92)):
            if base <= number < base + 3:
                return float(v[number - base])
            if base <= number < base + 9:
                return 0.0  # rotary and UVW axes: not on this machine
        if number == G92_FLAG_PARAM:
            return 1.0 if self.g92_applied else 0.0
        if number == ACTIVE_PARAM:
            return float(self.active)
        if WORK_PARAM <= number < WORK_PARAM + 9 * WORK_PARAM_STRIDE:
            system, axis = divmod(number - WORK_PARAM, WORK_PARAM_STRIDE)
            return float(self.work[system][axis]) if axis < 3 else 0.0
        return None
