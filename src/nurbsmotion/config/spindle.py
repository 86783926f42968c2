"""The ``spindle:`` section: one CiA-402 spindle drive in a velocity mode.

```yaml
spindle:
  node_id: 5
  eds: spindle.eds           # optional: the packaged servo description when not given
  mode: profile_velocity      # profile_velocity (CiA-402 mode 3) or csv (cyclic synchronous velocity, 9)
  counts_per_rev: 4096        # encoder counts per spindle revolution (0x60FF, 0x606C are counts/s)
  max_rpm: 24000              # S above this is refused at check, with file:line
  accel_rpm_s: 8000           # ramp (0x6083/0x6084 in mode 3, the master's ramp in mode 9)
  at_speed_timeout_s: 5.0     # M3/M4/S: motion waits at most this long for 'target reached'
```

``spindle: none`` (or no key) states there is no spindle: programs with M3/M4 are refused.
The description (EDS/DCF) is checked like an axis' one: 0x60FF target velocity, 0x606C
velocity actual, 0x6083 (+0x6084 or 0x60C5 for a ramp) in profile velocity mode, and the
mode's bit in 0x6502 supported drive modes when the file has that object (CiA 402-2).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from nurbsmotion.can import drive_od
from nurbsmotion.config.yaml_reading import MISSING, Doc, fields, number, optional, string
from nurbsmotion.can.drive_od import default_eds_path
from nurbsmotion.errors import InputError

if TYPE_CHECKING:  # canopen is imported only when a description is read (drive_od)
    from canopen.objectdictionary import ObjectDictionary

MONITOR_POLL_S = 0.05  # the master reads 0x6041 / 0x606C this often (fieldbus.spindle; counted in the bus load)


TARGET_VELOCITY = 0x60FF
VELOCITY_ACTUAL = 0x606C
PROFILE_ACCELERATION = 0x6083
PROFILE_DECELERATION = 0x6084
MAX_ACCELERATION = 0x60C5
SUPPORTED_DRIVE_MODES = 0x6502


class SpindleMode(str, enum.Enum):
    PROFILE_VELOCITY = "profile_velocity"  # CiA-402 mode 3: the drive ramps to 0x60FF, bit 10 'target reached'
    CSV = "csv"  # mode 9: the master sends 0x60FF, ramped, and judges 'at speed' from 0x606C

    @property
    def number(self) -> int:
        """0x6060 modes of operation value."""
        return 3 if self is SpindleMode.PROFILE_VELOCITY else 9

    @property
    def supported_bit(self) -> int:
        """Bit of 0x6502 that says the drive has this mode (CiA 402-2: pv bit 2, csv bit 8)."""
        return 2 if self is SpindleMode.PROFILE_VELOCITY else 8


@dataclass(frozen=True)
class SpindleConfig:
    node_id: int
    counts_per_rev: float
    max_rpm: float
    accel_rpm_s: float
    mode: SpindleMode = SpindleMode.PROFILE_VELOCITY
    at_speed_timeout_s: float = 5.0
    eds: str | None = None  # after loading: the file read (the packaged EDS when not given)
    od: ObjectDictionary | None = None

    def counts_s(self, rpm: float) -> int:
        """0x60FF value: counts/s = rpm · counts_per_rev / 60."""
        return int(round(rpm * self.counts_per_rev / 60.0))

    def rpm(self, counts_s: float) -> float:
        """rev/min = counts/s · 60 / counts_per_rev (0x606C -> rpm)."""
        return counts_s * 60.0 / self.counts_per_rev

    @property
    def accel_counts_s2(self) -> int:
        """0x6083/0x6084 value: counts/s² = accel_rpm_s · counts_per_rev / 60."""
        return max(1, self.counts_s(self.accel_rpm_s))


_POSITIVE = (number, {"minimum": 0.0})
_READERS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {
    "node_id": (number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 127}),
    "eds": (optional(string), {}),
    "mode": (string, {"choices": tuple(m.value for m in SpindleMode)}),
    "counts_per_rev": _POSITIVE,
    "max_rpm": _POSITIVE,
    "accel_rpm_s": _POSITIVE,
    "at_speed_timeout_s": _POSITIVE,
}
REQUIRED = ("node_id", "counts_per_rev", "max_rpm", "accel_rpm_s")


def read_spindle_drive(doc: Doc) -> Any:
    """``spindle: {node_id, ...}`` -> SpindleConfig (or MISSING after located errors)."""
    before = len(doc.errors)
    values = fields(doc, _READERS, required=REQUIRED)
    if len(doc.errors) > before or any(k not in values for k in REQUIRED):
        return MISSING
    if "mode" in values:
        values["mode"] = SpindleMode(values["mode"])
    return SpindleConfig(**values)


def description_problems(od: ObjectDictionary, mode: SpindleMode) -> list[str]:
    """What the described drive lacks for ``mode`` (CiA 402-2 objects and 0x6502 bit)."""
    needed = [TARGET_VELOCITY, VELOCITY_ACTUAL] + ([PROFILE_ACCELERATION] if mode is SpindleMode.PROFILE_VELOCITY else [])
    problems = [f"has no {drive_od.name_of(i, 0)}" for i in needed if drive_od.find(od, i) is None]
    supported = drive_od.find(od, SUPPORTED_DRIVE_MODES)
    default = None if supported is None else (supported.value if supported.value is not None else supported.default)
    if isinstance(default, int) and not default >> mode.supported_bit & 1:
        problems.append(f"0x6502 supported drive modes = 0x{default:08X}: no {mode.value} (mode {mode.number}, "
                        f"bit {mode.supported_bit})")
    return problems


def load_spindle_description(spindle: SpindleConfig, node_users: dict[int, str], where: Callable[[str], str],
                             base_dir: Path | None) -> SpindleConfig:
    """Check the spindle's node id against the other nodes (``node_users``: node id -> who),
    read its EDS (relative to the configuration's folder) and check it has what its mode
    needs; InputError at the YAML line (``where(path)``: ``file:line: path``)."""
    if spindle.node_id in node_users:
        raise InputError(where("spindle.node_id"), f"node id {spindle.node_id} is already used by "
                                                    f"{node_users[spindle.node_id]}")
    path = Path(spindle.eds) if spindle.eds else Path(default_eds_path())
    if spindle.eds and base_dir is not None and not path.is_absolute():
        path = (base_dir / path).resolve()
    place = where("spindle.eds" if spindle.eds else "spindle")
    try:
        od = drive_od.load_description(path, spindle.node_id)
    except drive_od.DescriptionError as err:
        raise InputError(place, str(err)) from None
    problems = description_problems(od, spindle.mode)
    if problems:
        raise InputError(place, f"{path.name} {'; '.join(problems)} (spindle node {spindle.node_id})")
    return replace(spindle, eds=str(path), od=od)
