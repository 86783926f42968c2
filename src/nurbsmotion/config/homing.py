"""The ``homing:`` section of an axis: schema and validation (errors at the YAML line).

```yaml
homing: {method: 17, speed_search_mm_s: 20, speed_zero_mm_s: 2, accel_mm_s2: 200, offset_mm: 0}
homing: {method: here, offset_mm: 0}
```

``method`` is the drive's CiA-402 homing method (0x6098: 1..35 and 37 standard, -128..-1
manufacturer specific) or ``here`` (no drive homing: the current position becomes
``offset_mm``). Drive methods other than 35/37 need the two speeds and the acceleration.
``order`` (an integer, lower homes first) sets the sequence of ``nurbsmotion home`` without
axis names (axes without it follow, in list order). ``ignore_limits`` (LinuxCNC's
HOME_IGNORE_LIMITS): the axis' io limit inputs neither refuse nor stop its homing (its limit
switch is also its home switch); any other limit input does. The optional
``speed_unit_counts_s``, ``accel_unit_counts_s2`` and ``home_offset_sign`` say what the
drive's units of 0x6099 / 0x609A are and which sign convention its 0x607C follows (see
``nurbsmotion.fieldbus.homing.homing_drive_values``): nothing in drive units is guessed.
``home_offset_object`` names a vendor object (0x2000-0x5FFF, sub-index 0) that takes the home
offset on a drive without 0x607C (maxon EPOS4: 0x30B0 "home position", the value the home
reads, so ``home_offset_sign: 1``); with it ``home_offset_sign`` must be given. Without either
object the master applies the offset itself (fieldbus.homing_check, docs/machine.md).

config.py calls :func:`read_homing` for ``axes[i].homing`` and :func:`read_axis_sim` for
``axes[i].sim`` (where a simulated drive's switches and index pulses are: the sensors homing
finds), this module imports config's YAML readers; config imports this module only when it
reads the section.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from nurbsmotion.config.yaml_reading import Doc, MISSING, SHOWN, boolean, fields, number

HERE = "here"
STANDARD_METHODS = tuple(range(1, 36)) + (37,)  # CiA 402-2: 1..35, 37 (36 reserved)
DRIVE_KEYS = ("speed_search_mm_s", "speed_zero_mm_s", "accel_mm_s2")
NO_MOTION_METHODS = (35, 37)  # the drive takes its current position as home: no speeds needed
VENDOR_OBJECTS = (0x2000, 0x5FFF)  # CiA 301 manufacturer-specific profile area


@dataclass(frozen=True)
class HomingConfig:
    """One axis' homing. ``method`` is an int (0x6098) or :data:`HERE`."""

    method: int | str
    offset_mm: float = 0.0
    speed_search_mm_s: float | None = None
    speed_zero_mm_s: float | None = None
    accel_mm_s2: float | None = None
    timeout_s: float = 60.0
    speed_unit_counts_s: float = 1.0  # counts/s one unit of 0x6099 stands for
    accel_unit_counts_s2: float = 1.0  # counts/s² one unit of 0x609A stands for
    home_offset_sign: int = -1  # -1: CiA 402 (zero = home + 0x607C, the home reads -0x607C)
    order: int | None = None  # `home` with no axis named: lower first; axes without: after, in list order
    ignore_limits: bool = False  # the io limit inputs of this axis do not stop its homing (LinuxCNC HOME_IGNORE_LIMITS)
    home_offset_object: int | None = None  # vendor object (sub 0) for the offset where the drive has no 0x607C

    @property
    def on_drive(self) -> bool:
        """True when the drive homes (mode 6); False for ``method: here``."""
        return self.method != HERE

    @property
    def moves(self) -> bool:
        """True when the drive's method searches (needs 0x6099 speeds and 0x609A)."""
        return self.on_drive and self.method not in NO_MOTION_METHODS


def _method(doc: Doc) -> Any:
    value = doc.value()
    if value == HERE:
        return HERE
    if isinstance(value, bool) or not isinstance(value, int):
        doc.fail(f"must be a CiA-402 homing method number or 'here', got {SHOWN.repr(value)}")
        return MISSING
    if not (value in STANDARD_METHODS or -128 <= value <= -1):
        doc.fail(f"homing method {value} is not defined by CiA 402 (1..35, 37; -128..-1 manufacturer specific)")
        return MISSING
    return value


def _sign(doc: Doc) -> Any:
    value = doc.value()
    if value not in (-1, 1) or isinstance(value, bool):
        doc.fail(f"must be -1 or 1, got {SHOWN.repr(value)}")
        return MISSING
    return value


def _vendor_object(doc: Doc) -> Any:
    value = doc.value()
    low, high = VENDOR_OBJECTS
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        shown = f"0x{value:04X}" if isinstance(value, int) and not isinstance(value, bool) else SHOWN.repr(value)
        doc.fail(f"must be a manufacturer-specific object 0x{low:04X}..0x{high:04X}, got {shown} (0x607C is used "
                 f"by itself where the drive's EDS lists it)")
        return MISSING
    return value


_POSITIVE = (number, {"minimum": 0})
_READERS = {
    "method": (_method, {}),
    "offset_mm": (number, {}),
    "speed_search_mm_s": _POSITIVE,
    "speed_zero_mm_s": _POSITIVE,
    "accel_mm_s2": _POSITIVE,
    "timeout_s": _POSITIVE,
    "speed_unit_counts_s": _POSITIVE,
    "accel_unit_counts_s2": _POSITIVE,
    "home_offset_sign": (_sign, {}),
    "order": (number, {"integer": True, "minimum": 0, "exclusive_min": False}),
    "ignore_limits": (boolean, {}),
    "home_offset_object": (_vendor_object, {}),
}


def read_homing(doc: Doc) -> Any:
    """``axes[i].homing`` -> HomingConfig (or MISSING after recording located errors)."""
    before = len(doc.errors)
    values = fields(doc, _READERS, required=("method",))
    method = values.get("method")
    missing = [key for key in DRIVE_KEYS if key not in values]
    if method not in (None, HERE, *NO_MOTION_METHODS) and missing and len(doc.errors) == before:
        doc.fail(f"homing method {method} runs on the drive and needs {', '.join(missing)}")
    if "home_offset_object" in values and "home_offset_sign" not in values and len(doc.errors) == before:
        doc.fail(f"home_offset_object 0x{values['home_offset_object']:04X} needs home_offset_sign (1: the home reads "
                 f"the value written, -1: it reads minus it; see the drive's manual)")
    if len(doc.errors) > before or method is None:
        return MISSING
    return HomingConfig(**values)


@dataclass(frozen=True)
class AxisSimSensors:
    """``axes[i].sim``: where the simulated drive of this axis has its limit switches and
    index pulses, in machine mm (the axis map's coordinates at power-on, before any homing).
    Used only when the drives are simulated (``simulate: true``, ``nurbsmotion sim``)."""

    negative_limit_mm: float | None = None  # a switch active at and below this position
    positive_limit_mm: float | None = None  # ... at and above
    index_pitch_mm: float | None = None  # encoder index pulses every this many mm
    index_phase_mm: float = 0.0  # the position of one index pulse


_SIM_READERS = {
    "negative_limit_mm": (number, {}),
    "positive_limit_mm": (number, {}),
    "index_pitch_mm": _POSITIVE,
    "index_phase_mm": (number, {}),
}


def read_axis_sim(doc: Doc) -> Any:
    """``axes[i].sim`` -> AxisSimSensors (or MISSING after recording located errors)."""
    before = len(doc.errors)
    values = fields(doc, _SIM_READERS)
    low, high = values.get("negative_limit_mm"), values.get("positive_limit_mm")
    if low is not None and high is not None and low >= high:
        doc.fail(f"negative_limit_mm {low:g} must be below positive_limit_mm {high:g}")
    if len(doc.errors) > before:
        return MISSING
    return AxisSimSensors(**values)


def homing_method_name(method: int | str) -> str:
    """A short human name of a method, for logs and status (CiA 402-2 homing methods)."""
    return _METHOD_NAMES.get(method, f"method {method}")


_METHOD_NAMES: dict[int | str, str] = {
    HERE: "here (current position)",
    1: "negative limit switch + index",
    2: "positive limit switch + index",
    17: "negative limit switch",
    18: "positive limit switch",
    33: "index pulse, negative direction",
    34: "index pulse, positive direction",
    35: "current position",
    37: "current position",
}

