"""What one axis' drive homing writes, decided from the drive's own EDS/DCF and checked
against it before the bus is touched. Pure: no bus, no SDO (as fieldbus.bringup_plan).

The objects of CiA 402-2 homing mode, each listed in the file, writable and within its
LowLimit..HighLimit (CiA 306; no file of tests/data/eds gives a value list instead):

- homing mode itself: 0x6502 bit 5 where the file gives 0x6502's value, 0x6060 taking 6,
  0x6061 to read it back;
- 0x6098 = the method (Elmo allows -128..35, ZeroErr 0..35, Pilz declares it ``const``,
  Schunk's PRL120 has none);
- for a method that moves (not 35/37): 0x6099:01/02 speeds and 0x609A acceleration;
- the home offset, by :class:`OffsetRoute`: ``0x607C`` value (``homing_drive_values``) 0:
  nothing is written; else the vendor object named by ``homing.home_offset_object`` (the
  YAML's choice, even where the file lists 0x607C); else 0x607C where the file lists it;
  else the master applies it (LinuxCNC's HOME_OFFSET is done
  in software too): the drive's home reads 0 counts (its own home offset, 0 as shipped) and
  the axis map's ``offset_counts`` becomes ``-round(±offset_mm · counts_per_mm)``, so that
  machine position = ±(counts - offset_counts)/counts_per_mm reads ``offset_mm`` at the home.

Whichever route, ``offset_mm`` means one thing: the machine position of the home.
A homing the drive cannot do is one :class:`InputError` naming the configuration line,
the axis, the node, the EDS file and the object.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path

from canopen.objectdictionary import ObjectDictionary, datatypes

from nurbsmotion.can import cia402 as c
from nurbsmotion.can import drive_od
from nurbsmotion.config import AxisConfig, MachineConfig, axis_where
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.drive_state import mode_of
from nurbsmotion.fieldbus.homing import (HOME_OFFSET, HOMING_ACCELERATION, HOMING_METHOD, HOMING_SPEEDS, MODE_HOMING,
                                         HomingPlan, OffsetObject, here_offset_counts, homing_drive_values,
                                         homing_plan)
from nurbsmotion.config.homing import HERE, HomingConfig

HOMING_MODE_BIT = 5  # 0x6502 bit of homing mode (CiA 402-2)
STRUCT_CODES = {datatypes.INTEGER8: "<b", datatypes.INTEGER16: "<h", datatypes.INTEGER32: "<i",
                datatypes.UNSIGNED8: "<B", datatypes.UNSIGNED16: "<H", datatypes.UNSIGNED32: "<I"}
# the configuration key each homing object comes from, for the error's place
FIELD_OF = {HOMING_METHOD: "homing.method", HOMING_SPEEDS: "homing.speed_search_mm_s",
            HOMING_ACCELERATION: "homing.accel_mm_s2", c.MODES_OF_OPERATION: "homing.method"}
OBJECT_NAMES = {HOMING_METHOD: "homing method", HOMING_SPEEDS: "homing speeds", HOMING_ACCELERATION:
                "homing acceleration", HOME_OFFSET: "home offset", c.MODES_OF_OPERATION: "modes of operation"}


class OffsetRoute(enum.Enum):
    """How the home comes to read ``offset_mm`` (module docstring)."""

    NONE = "0: nothing written"
    DRIVE = "0x607C (home offset)"
    VENDOR = "vendor object"
    MASTER = "applied by the master"


@dataclass(frozen=True)
class AxisHoming:
    """One axis' drive homing: the SDO plan, the offset route and the axis map offset the
    axis has after a completed homing (counts = ±mm·counts_per_mm + offset_counts)."""

    axis_index: int
    method: int
    plan: HomingPlan
    route: OffsetRoute
    offset_counts_after: int

    def describe(self) -> list[str]:
        """``drives check`` lines: what the homing writes and how the offset is applied."""
        writes = ", ".join(f"{drive_od.name_of(w.index, w.subindex)} = {w.value}" for w in self.plan.writes)
        offset = self.route.value
        if self.route is OffsetRoute.VENDOR:
            vendor = next(w for w in self.plan.writes if w.index not in OBJECT_NAMES)
            offset = f"vendor object 0x{vendor.index:04X}"
        elif self.route is OffsetRoute.MASTER:
            offset = f"applied by the master (the drive has no 0x607C): offset_counts {self.offset_counts_after}"
        return [f"  home    method {self.method}: write {writes}; 0x6061 must read {MODE_HOMING}",
                f"  home    offset: {offset}"]


class _Refusal(Exception):
    def __init__(self, message: str, field_name: str) -> None:
        super().__init__(message)
        self.field_name = field_name


def plan_homing(config: MachineConfig, i: int) -> AxisHoming | None:
    """Axis ``i``'s drive homing (None: no ``homing:`` or ``method: here``); InputError naming
    line, axis, node, EDS and object when the drive cannot do it."""
    axis = config.axes[i]
    homing = axis.homing
    if homing is None or not homing.on_drive:
        return None
    if axis.od is None:
        raise InputError(axis_where(config, i, "eds"), "no object dictionary loaded (use load_config/parse_config)")
    try:
        return _plan(axis, i, axis.od, homing)
    except _Refusal as refusal:
        raise InputError(axis_where(config, i, refusal.field_name), str(refusal)) from None


def offered_homing(axis: AxisConfig, wanted: HomingConfig) -> HomingConfig:
    """``wanted`` if the axis' drive can do it, else ``here`` with its offset and order (the
    demo homes every drive with what its EDS offers)."""
    if not wanted.on_drive or axis.od is None:
        return wanted
    try:
        _plan(axis, 0, axis.od, wanted)
    except _Refusal:
        return HomingConfig(method=HERE, offset_mm=wanted.offset_mm, order=wanted.order,
                            ignore_limits=wanted.ignore_limits)
    return wanted


def _plan(axis: AxisConfig, i: int, od: ObjectDictionary, homing: HomingConfig) -> AxisHoming:
    eds = Path(axis.eds).name if axis.eds else "(no EDS)"
    assert isinstance(homing.method, int)
    _check_homing_mode(od, eds, homing.method)
    try:
        values = homing_drive_values(homing, axis.counts_per_mm, axis.invert, axis.offset_counts, axis.name)
    except InputError as err:
        raise _Refusal(err.message, err.where.rsplit(": ", 1)[-1]) from None
    route, target = _offset_route(od, eds, homing, values.home_offset)
    plan = homing_plan(values, mode_of(axis), target)
    for write in plan.writes:
        _check_write(od, eds, homing.method, write.index, write.subindex, write.value)
    after = here_offset_counts(0, homing.offset_mm, axis.counts_per_mm, axis.invert) \
        if route is OffsetRoute.MASTER else axis.offset_counts
    return AxisHoming(i, homing.method, plan, route, after)


def _check_homing_mode(od: ObjectDictionary, eds: str, method: int) -> None:
    """0x6502 (value or default) must have bit 5 where the file says; 0x6061 must exist."""
    modes = drive_od.find(od, c.SUPPORTED_DRIVE_MODES, 0)
    bits = None if modes is None else (modes.value if modes.value is not None else modes.default)
    if bits is not None and not bits >> HOMING_MODE_BIT & 1:
        raise _Refusal(f"{eds}'s 0x6502:00 (supported drive modes) = 0x{bits:08X} lacks bit {HOMING_MODE_BIT} "
                       f"(homing mode), so homing method {method} is not possible; use method: here",
                       "homing.method")
    if drive_od.find(od, c.MODES_OF_OPERATION_DISPLAY, 0) is None:
        raise _Refusal(f"{eds} has no 0x6061:00 (modes of operation display) to read homing mode back, so homing "
                       f"method {method} is not possible; use method: here", "homing.method")


def _offset_route(od: ObjectDictionary, eds: str, homing: HomingConfig,
                  value: int) -> tuple[OffsetRoute, OffsetObject | None]:
    if value == 0:
        return OffsetRoute.NONE, None
    if homing.home_offset_object is not None:
        var = drive_od.find(od, homing.home_offset_object, 0)
        if var is None or var.data_type not in STRUCT_CODES:
            what = "has no" if var is None else f"has a non-integer ({drive_od.type_name(var)})"
            raise _Refusal(f"{eds} {what} {drive_od.name_of(homing.home_offset_object, 0)} to take the home offset",
                           "homing.home_offset_object")
        return OffsetRoute.VENDOR, OffsetObject(homing.home_offset_object, 0, STRUCT_CODES[var.data_type])
    if drive_od.find(od, HOME_OFFSET, 0) is not None:
        return OffsetRoute.DRIVE, OffsetObject()
    return OffsetRoute.MASTER, None


def _check_write(od: ObjectDictionary, eds: str, method: int, index: int, subindex: int, value: int) -> None:
    var = drive_od.find(od, index, subindex)
    where = drive_od.name_of(index, subindex)
    name = OBJECT_NAMES.get(index, "home offset")
    field_name = FIELD_OF.get(index, "homing.offset_mm")
    if index == HOMING_SPEEDS and subindex == 2:
        field_name = "homing.speed_zero_mm_s"
    need = f"needed for homing method {method}"
    if var is None:
        raise _Refusal(f"{eds} has no {where} ({name}), {need}; use method: here", field_name)
    problem = drive_od.write_problem(var, value)
    if problem:
        raise _Refusal(f"{eds}'s {where} ({var.name}) {problem}, {need}; use method: here", field_name)
