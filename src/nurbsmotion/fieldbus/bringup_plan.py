"""What bring-up writes to one drive, derived from its own object dictionary (EDS/DCF) and
checked against it before the bus is touched. Pure: no bus, no SDO.

Per axis, in PRE-OPERATIONAL (CiA 301 §7.3.2, CiA 402 §8): 0x6060 mode (read back from
0x6061); IP: 0x60C0 sub-mode 0 (if present), 0x60C2 period; CSP: 0x60C2 where present (the
drive interpolates over it); 0x1006 cycle period and 0x1007 SYNC window (``bus.sync_window_us``,
default 0 = none) where present;
0x605A quick-stop option within 1-4 (QUICK STOP ACTIVE ends in SWITCH ON DISABLED, so a
queued 'enable operation' cannot re-enable the drive, CiA 402 transition 16); the PDOs; 0x6065
/0x6066 following error window/time-out where present and in range; 0x1017 heartbeat
producer; 0x1016:01 consuming the master's heartbeat where present; 0x6085 only when
configured in the drive's own units; then the axis' ``sdo:`` list.

A needed object the drive lacks, cannot write, cannot map or whose range excludes the value
is one :class:`InputError` naming the configuration line, the axis, the node, the EDS file
and the object. Optional objects the drive lacks are skipped and listed in ``skipped``.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

from canopen.objectdictionary import ObjectDictionary

from nurbsmotion.can import cia402 as c
from nurbsmotion.can import drive_od
from nurbsmotion.config import MachineConfig, axis_where
from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.fieldbus.busload import HEARTBEAT_DLC, SYNC_DLC, fits_following_error_tpdo, frame_bits
from nurbsmotion.fieldbus.drive_state import mode_of
from nurbsmotion.fieldbus.homing_check import AxisHoming, plan_homing
from nurbsmotion.fieldbus.pdo import interpolation_period, mapping_entry


QUICK_STOP_OPTIONS = (2, 1, 3, 4)  # preferred first: 2 = quick-stop ramp 0x6085, then SWITCH ON DISABLED
MAX_PDO_BITS = 64
MODE_WORDS = {c.Mode.INTERPOLATED_POSITION: "interpolated position (mode 7)",
              c.Mode.CYCLIC_SYNC_POSITION: "cyclic synchronous position (mode 8)"}
SETPOINT_OBJECT = {c.Mode.INTERPOLATED_POSITION: (c.IP_DATA_RECORD, 1), c.Mode.CYCLIC_SYNC_POSITION: (c.TARGET_POSITION, 0)}


class Field(enum.Enum):
    """What one PDO entry carries, with its object and struct code (little endian)."""

    CONTROLWORD = (c.CONTROLWORD, 0, "H")
    SETPOINT_IP = (c.IP_DATA_RECORD, 1, "i")
    SETPOINT_CSP = (c.TARGET_POSITION, 0, "i")
    STATUSWORD = (c.STATUSWORD, 0, "H")
    POSITION = (c.POSITION_ACTUAL, 0, "i")
    FOLLOWING_ERROR = (c.FOLLOWING_ERROR_ACTUAL, 0, "i")

    @property
    def index(self) -> int:
        return self.value[0]

    @property
    def subindex(self) -> int:
        return self.value[1]

    @property
    def code(self) -> str:
        return self.value[2]

    @property
    def bits(self) -> int:
        return struct.calcsize("<" + self.code) * 8

    @property
    def is_setpoint(self) -> bool:
        return self in (Field.SETPOINT_IP, Field.SETPOINT_CSP)


@dataclass(frozen=True)
class PdoFrame:
    """One PDO of the cyclic exchange: COB-ID, the fields in order and their struct."""

    kind: str  # 'RPDO' (master -> drive) or 'TPDO' (drive -> master)
    number: int  # 1..4
    cob_id: int
    fields: tuple[Field, ...]

    @property
    def fmt(self) -> struct.Struct:
        return struct.Struct("<" + "".join(f.code for f in self.fields))

    @property
    def dlc(self) -> int:
        return self.fmt.size


def rpdo_packer(frame: PdoFrame) -> Callable[[bytearray, int, int], None]:
    """``pack(data, controlword, setpoint)`` filling one RPDO of ``frame``'s layout in place
    (what the cycle loop calls per frame; no allocation)."""
    pack_into = frame.fmt.pack_into
    if frame.fields[0] is Field.CONTROLWORD and len(frame.fields) == 2:
        return lambda data, cw, sp: pack_into(data, 0, cw, sp)
    if frame.fields == (Field.CONTROLWORD,):
        return lambda data, cw, sp: pack_into(data, 0, cw)
    if len(frame.fields) == 1 and frame.fields[0].is_setpoint:
        return lambda data, cw, sp: pack_into(data, 0, sp)
    raise ValueError(f"{frame.kind}{frame.number}: not a set-point PDO: {frame.fields}")


@dataclass(frozen=True)
class AxisPdoLayout:
    """The per-cycle frames of one axis, as bring-up configures them.

    ``rpdos``: what the master sends after each SYNC (controlword + set-point in one frame,
    or controlword and set-point in two when one PDO cannot carry both). ``tpdos``: what the
    drive sends at each SYNC (statusword + position actual, maybe split; the following error
    0x60F4 only when the drive has it and the bus load allows)."""

    node_id: int
    rpdos: tuple[PdoFrame, ...]
    tpdos: tuple[PdoFrame, ...]

    @property
    def has_following_error(self) -> bool:
        return any(Field.FOLLOWING_ERROR in f.fields for f in self.tpdos)

    def frame_with(self, fld: Field) -> PdoFrame:
        return next(f for f in self.rpdos + self.tpdos if fld in f.fields)


@dataclass(frozen=True)
class Write:
    """One SDO download, typed by the EDS (canopen encodes ``value`` from its data type)."""

    step: str
    index: int
    subindex: int
    value: int
    why: str = ""


@dataclass(frozen=True)
class ReadBack:
    """An SDO upload that must answer ``expect`` (0x6061 after 0x6060)."""

    step: str
    index: int
    subindex: int
    expect: int


@dataclass(frozen=True)
class PdoSetup:
    """Map one PDO through canopen's PdoMap (disable, clear, add, save = CiA 301 order), or
    disable it (``frame`` None: COB-ID bit 31)."""

    step: str
    kind: str
    number: int
    cob_id: int
    frame: PdoFrame | None


Step = Write | ReadBack | PdoSetup


@dataclass(frozen=True)
class Skipped:
    what: str  # object, e.g. '0x6066:00'
    reason: str


@dataclass(frozen=True)
class DrivePlan:
    axis_index: int
    axis: str
    node_id: int
    eds: str  # file name
    mode: c.Mode
    check_supported_modes: bool  # 0x6502 readable: read it at bring-up
    steps: tuple[Step, ...]
    layout: AxisPdoLayout
    skipped: tuple[Skipped, ...] = field(default=())
    homing: AxisHoming | None = None  # the drive homing (fieldbus.homing_check), None: none or 'here'


class _Refusal(Exception):
    def __init__(self, message: str, field_name: str = "") -> None:
        super().__init__(message)
        self.field_name = field_name


def pdo_cob_id(kind: str, number: int, node_id: int) -> int:
    """Pre-defined connection set (CiA 301 §7.3.5): TPDOn 0x180 + 0x100(n-1), RPDOn 0x200 + ..."""
    return (c.COB_RPDO if kind == "RPDO" else c.COB_TPDO)[number - 1] + node_id


def pdo_capacity(od: ObjectDictionary, kind: str, number: int) -> tuple[int, str]:
    """How many entries PDO ``number`` can map (0 with the reason when it cannot be used)."""
    comm = (c.RPDO_COMM if kind == "RPDO" else c.TPDO_COMM) + number - 1
    mapping = (c.RPDO_MAPPING if kind == "RPDO" else c.TPDO_MAPPING) + number - 1
    cob, trans, count = drive_od.find(od, comm, 1), drive_od.find(od, comm, 2), drive_od.find(od, mapping, 0)
    if cob is None or count is None:
        return 0, f"has no {kind}{number} (0x{comm:04X}/0x{mapping:04X})"
    if not cob.writable or trans is None or not trans.writable:
        return 0, f"{kind}{number}'s COB-ID or transmission type (0x{comm:04X}:01/02) is read-only"
    if not count.writable:
        return 0, f"{kind}{number}'s mapping (0x{mapping:04X}) is fixed (read-only)"
    entries = drive_od.sub_count(od, mapping)
    if count.max is not None:
        entries = min(entries, count.max)
    return entries, ""


def _mappable_problem(od: ObjectDictionary, fld: Field, kind: str) -> str | None:
    var = drive_od.find(od, fld.index, fld.subindex)
    where = drive_od.name_of(fld.index, fld.subindex)
    if var is None:
        return f"has no {where}"
    if not var.pdo_mappable:
        return f"does not allow {where} ({var.name}) in a PDO (PDOMapping=0)"
    if kind == "RPDO" and not var.writable:
        return f"has {where} ({var.name}) read-only"
    if drive_od.bits(var) != fld.bits or (var.data_type in (0x5, 0x6, 0x7)) != (fld.code in "BHI"):
        return f"has {where} ({var.name}) as {drive_od.type_name(var)}; the master needs {fld.bits}-bit " \
               f"{'unsigned' if fld.code in 'BHI' else 'signed'}"
    return None


def _place(od: ObjectDictionary, kind: str, groups: list[tuple[Field, ...]], first: int,
           split: list[tuple[Field, ...]] | None) -> list[PdoFrame] | None:
    """Frames for ``groups`` from PDO ``first`` on (each group in one PDO), else the
    ``split`` grouping, else None. A group fits when the PDO allows as many entries and
    64 bits."""
    for grouping in (groups, split):
        if grouping is None:
            continue
        frames, number = [], first
        for group in grouping:
            while number <= 4 and pdo_capacity(od, kind, number)[0] < len(group):
                number += 1
            if number > 4 or sum(f.bits for f in group) > MAX_PDO_BITS:
                break
            frames.append(PdoFrame(kind, number, 0, group))
            number += 1
        else:
            return frames
    return None


def _with_cob(frames: list[PdoFrame], node_id: int) -> tuple[PdoFrame, ...]:
    return tuple(PdoFrame(f.kind, f.number, pdo_cob_id(f.kind, f.number, node_id), f.fields) for f in frames)


def _mode_problem(od: ObjectDictionary, mode: c.Mode, eds: str) -> str | None:
    """Why ``mode`` is impossible on this drive (one clause), else None."""
    sp = Field.SETPOINT_IP if mode == c.Mode.INTERPOLATED_POSITION else Field.SETPOINT_CSP
    for fld, kind in ((Field.CONTROLWORD, "RPDO"), (sp, "RPDO"), (Field.STATUSWORD, "TPDO"), (Field.POSITION, "TPDO")):
        problem = _mappable_problem(od, fld, kind)
        if problem:
            return f"{eds} {problem}"
    modes = drive_od.find(od, c.SUPPORTED_DRIVE_MODES, 0)
    if modes is not None and modes.default is not None and not modes.default >> c.SUPPORTED_MODE_BIT[mode] & 1:
        return f"{eds}'s 0x6502 (supported drive modes) = 0x{modes.default:08X} lacks bit {c.SUPPORTED_MODE_BIT[mode]}"
    mode_var = drive_od.find(od, c.MODES_OF_OPERATION, 0)
    if mode_var is None:
        return f"{eds} has no 0x6060:00 (modes of operation)"
    problem = drive_od.write_problem(mode_var, int(mode))
    if problem:
        return f"{eds}'s 0x6060:00 (modes of operation) {problem}"
    if mode == c.Mode.INTERPOLATED_POSITION:
        problem = _ip_period_problem(od, eds)
        if problem:
            return problem
        sub_mode = drive_od.find(od, c.IP_SUB_MODE, 0)
        if sub_mode is not None and drive_od.write_problem(sub_mode, 0) and sub_mode.default != 0:
            span = drive_od.allowed_range(sub_mode)
            return f"{eds}'s 0x60C0:00 (interpolation sub-mode) allows {span[0]}..{span[1]}, not 0 (linear)" \
                if span else f"{eds}'s 0x60C0:00 cannot be set to 0 (linear)"
    return None


def _ip_period_problem(od: ObjectDictionary, eds: str) -> str | None:
    """IP interpolates over one period: 0x60C2 (value and exponent), or for a drive without
    0x60C2 (Technosoft IDM/ISD860: IP in 0x6502, no 0x60C2) a writable 0x1006 cycle period in
    µs, which such drives take as their interpolation period (CiA 301 §7.5.2.6)."""
    missing = [sub for sub in (1, 2) if drive_od.find(od, c.IP_TIME_PERIOD, sub) is None]
    if not missing:
        return None
    cycle = drive_od.find(od, c.COMM_CYCLE_PERIOD, 0)
    if len(missing) == 2 and cycle is not None and cycle.writable:
        return None
    return f"{eds} has no 0x60C2:{missing[0]:02X} (interpolation time period)" + \
        ("" if len(missing) == 1 else " and no writable 0x1006 (communication cycle period) to take it from")


def offered_modes(od: ObjectDictionary, eds: str) -> list[c.Mode]:
    return [m for m in MODE_WORDS if _mode_problem(od, m, eds) is None]


def _check_mode(od: ObjectDictionary, mode: c.Mode, eds: str) -> None:
    problem = _mode_problem(od, mode, eds)
    if problem is None:
        return
    offers = offered_modes(od, eds)
    offered = " and ".join(MODE_WORDS[m] for m in offers) if offers else "neither interpolated position (7) nor " \
        "cyclic synchronous position (8)"
    raise _Refusal(f"{problem}, so {MODE_WORDS[mode]} is not possible; it offers {offered}", "mode")


class _Builder:
    """Collects the steps and skipped objects of one drive's plan."""

    def __init__(self, od: ObjectDictionary, eds: str) -> None:
        self.od, self.eds = od, eds
        self.steps: list[Step] = []
        self.skipped: list[Skipped] = []

    def write(self, step: str, index: int, subindex: int, value: int, why: str = "", *,
              optional: bool = False, field_name: str = "") -> bool:
        """Plan a write; an optional object the drive lacks (or whose range excludes the
        value) is skipped, a needed one is refused. True if planned."""
        var = drive_od.find(self.od, index, subindex)
        where = drive_od.name_of(index, subindex)
        if var is None:
            if optional:
                self.skipped.append(Skipped(where, f"{self.eds} has no {where}: left to the drive"))
                return False
            raise _Refusal(f"{self.eds} has no {where}, needed to {step}", field_name)
        problem = drive_od.write_problem(var, value)
        if problem:
            if optional:
                self.skipped.append(Skipped(where, f"{where} ({var.name}) {problem}: left to the drive"))
                return False
            raise _Refusal(f"{self.eds}'s {where} ({var.name}) {problem}, needed to {step}", field_name)
        self.steps.append(Write(step, index, subindex, value, why))
        return True


def _period_writes(b: _Builder, mode: c.Mode, period_s: float, window_us: int) -> None:
    ip = mode == c.Mode.INTERPOLATED_POSITION
    if ip:
        b.write("set interpolation sub-mode", c.IP_SUB_MODE, 0, 0, "linear interpolation", optional=True)
    exponent_var = drive_od.find(b.od, c.IP_TIME_PERIOD, 2)
    if exponent_var is not None:
        fixed = None if exponent_var.writable else exponent_var.default
        try:
            value, exponent = interpolation_period(period_s, fixed)
        except ValueError as err:
            raise _Refusal(f"{b.eds}: {err}", "mode") from None
        if b.write("set interpolation period", c.IP_TIME_PERIOD, 1, value, f"{value}·10^{exponent} s",
                   optional=not ip, field_name="mode"):
            if exponent_var.writable:
                b.write("set interpolation period", c.IP_TIME_PERIOD, 2, exponent, "exponent", field_name="mode")
            else:
                b.skipped.append(Skipped("0x60C2:02", f"read-only, fixed at {exponent}: the value is scaled to it"))
    else:
        b.skipped.append(Skipped("0x60C2", f"{b.eds} has no 0x60C2: the drive takes the cycle from "
                                 + ("0x1006" if ip else "SYNC")))
    period_us = round(period_s * 1e6)
    b.write("set cycle period", c.COMM_CYCLE_PERIOD, 0, period_us,
            f"{period_us} µs" + (" (the interpolation period: no 0x60C2)" if ip and exponent_var is None else ""),
            optional=not (ip and exponent_var is None), field_name="mode")
    b.write("set SYNC window", 0x1007, 0, window_us, "0 = no window (bus.sync_window_us)" if window_us == 0
            else f"{window_us} µs: later RPDOs are discarded", optional=True)


def _quick_stop_option(b: _Builder) -> None:
    var = drive_od.find(b.od, c.QUICK_STOP_OPTION, 0)
    if var is None:
        b.skipped.append(Skipped("0x605A:00", f"{b.eds} has no 0x605A: the drive's own quick-stop reaction"))
        return
    if not var.writable:
        if var.default is not None and 5 <= var.default <= 8:
            raise _Refusal(f"{b.eds}'s 0x605A:00 (quick stop option) is read-only at {var.default} (stays in QUICK "
                           f"STOP ACTIVE, where 'enable operation' re-enables the drive); 1-4 is needed")
        b.skipped.append(Skipped("0x605A:00", f"read-only at {var.default}"))
        return
    for option in QUICK_STOP_OPTIONS:
        if drive_od.write_problem(var, option) is None:
            b.steps.append(Write("set quick stop option", c.QUICK_STOP_OPTION, 0, option,
                                 "quick stop ends in SWITCH ON DISABLED"))
            return
    span = drive_od.allowed_range(var)
    raise _Refusal(f"{b.eds}'s 0x605A:00 (quick stop option) allows {span}, none of 1-4 (quick stop ending in "
                   f"SWITCH ON DISABLED)")


def _pdo_steps(b: _Builder, mode: c.Mode, node_id: int, following_error: bool) -> AxisPdoLayout:
    sp = Field.SETPOINT_IP if mode == c.Mode.INTERPOLATED_POSITION else Field.SETPOINT_CSP
    rpdos = _place(b.od, "RPDO", [(Field.CONTROLWORD, sp)], 1, [(Field.CONTROLWORD,), (sp,)])
    if rpdos is None:
        raise _Refusal(f"{b.eds}: no RPDO can carry the controlword and the set-point (one PDO with 2 entries or "
                       f"two with 1): {pdo_capacity(b.od, 'RPDO', 1)[1] or 'RPDO1 maps fewer entries'}", "mode")
    tpdos = _place(b.od, "TPDO", [(Field.STATUSWORD, Field.POSITION)], 1, [(Field.STATUSWORD,), (Field.POSITION,)])
    if tpdos is None:
        raise _Refusal(f"{b.eds}: no TPDO can carry the statusword and the position actual value: "
                       f"{pdo_capacity(b.od, 'TPDO', 1)[1] or 'TPDO1 maps fewer entries'}", "mode")
    if following_error:
        fe = _mappable_problem(b.od, Field.FOLLOWING_ERROR, "TPDO")
        extra = None if fe else _place(b.od, "TPDO", [(Field.FOLLOWING_ERROR,)], tpdos[-1].number + 1, None)
        if extra:
            tpdos += extra
        else:
            b.skipped.append(Skipped("0x60F4:00", f"{b.eds} {fe or 'has no free TPDO for it'}: the master computes "
                                     f"the following error"))
    else:
        b.skipped.append(Skipped("0x60F4:00", "no TPDO for it under monitoring.max_bus_load: the master computes "
                                 "the following error"))
    layout = AxisPdoLayout(node_id, _with_cob(rpdos, node_id), _with_cob(tpdos, node_id))
    for kind, frames in (("RPDO", layout.rpdos), ("TPDO", layout.tpdos)):
        used = {f.number: f for f in frames}
        for number in range(1, 5):
            cob_id = pdo_cob_id(kind, number, node_id)
            if number in used:
                b.steps.append(PdoSetup(f"map {kind}{number}", kind, number, cob_id, used[number]))
            elif drive_od.find(b.od, (c.RPDO_COMM if kind == "RPDO" else c.TPDO_COMM) + number - 1, 1) is not None:
                b.write(f"disable {kind}{number}", (c.RPDO_COMM if kind == "RPDO" else c.TPDO_COMM) + number - 1, 1,
                        c.PDO_COB_ID_INVALID | cob_id, "not used: no bus load", optional=True)
    return layout


def plan_drive(config: MachineConfig, i: int, following_error_window_counts: int,
               following_error_tpdo: bool) -> DrivePlan:
    """The bring-up plan of axis ``i`` (raises InputError naming line, axis, node, EDS, object)."""
    axis = config.axes[i]
    od = axis.od
    eds = Path(axis.eds).name if axis.eds else "(no EDS)"
    if od is None:
        raise InputError(axis_where(config, i, "eds"), "no object dictionary loaded (use load_config/parse_config)")
    try:
        plan = _plan(config, i, od, eds, following_error_window_counts, following_error_tpdo)
    except _Refusal as refusal:
        raise InputError(axis_where(config, i, refusal.field_name), str(refusal)) from None
    return replace(plan, homing=plan_homing(config, i))


def _plan(config: MachineConfig, i: int, od: ObjectDictionary, eds: str, window_counts: int,
          following_error_tpdo: bool) -> DrivePlan:
    axis, mon = config.axes[i], config.monitoring
    mode = mode_of(axis)
    _check_mode(od, mode, eds)
    b = _Builder(od, eds)
    b.write("set mode", c.MODES_OF_OPERATION, 0, int(mode), MODE_WORDS[mode], field_name="mode")
    if drive_od.find(od, c.MODES_OF_OPERATION_DISPLAY, 0) is not None:
        b.steps.append(ReadBack("read mode back", c.MODES_OF_OPERATION_DISPLAY, 0, int(mode)))
    else:
        b.skipped.append(Skipped("0x6061:00", f"{eds} has no 0x6061: the mode is not read back"))
    _period_writes(b, mode, config.cycle_period_s, config.bus.sync_window_us)
    _quick_stop_option(b)
    layout = _pdo_steps(b, mode, axis.node_id, following_error_tpdo)
    b.write("set following error window", c.FOLLOWING_ERROR_WINDOW, 0, window_counts, "counts", optional=True)
    b.write("set following error time-out", c.FOLLOWING_ERROR_TIMEOUT, 0, axis.following_error_timeout_ms, "ms",
            optional=True)
    b.write("set heartbeat producer", c.PRODUCER_HEARTBEAT_TIME, 0, mon.heartbeat_producer_ms, "ms: the master "
            "watches it", field_name="node_id")
    _heartbeat_consumer(b, config)
    if axis.quick_stop_decel is not None:
        b.write("set quick stop deceleration", c.QUICK_STOP_DECELERATION, 0, axis.quick_stop_decel,
                "drive units, as configured", field_name="quick_stop_decel")
    else:
        b.skipped.append(Skipped("0x6085:00", "quick_stop_decel not configured: the drive's own value"))
    owned = _objects_written(b.steps)
    for entry in axis.sdo:
        problem = _sdo_overrides_plan(entry.index, entry.value, owned)
        if problem:
            raise InputError(f"{entry.where} ({axis.name}, node {axis.node_id})", f"{eds}: {problem}")
        b.steps.append(Write("write sdo list", entry.index, entry.subindex, entry.value, entry.where))
    modes = drive_od.find(od, c.SUPPORTED_DRIVE_MODES, 0)
    return DrivePlan(i, axis.name, axis.node_id, eds, mode, modes is not None and modes.readable,
                     tuple(b.steps), layout, tuple(b.skipped))


# objects the bring-up writes itself -> the configuration that sets them
OWNER_KEYS = {
    c.MODES_OF_OPERATION: "axes[].mode", c.COMM_CYCLE_PERIOD: "cycle_period_ms", c.IP_TIME_PERIOD: "cycle_period_ms",
    c.IP_SUB_MODE: "nothing (linear interpolation is required)",
    c.FOLLOWING_ERROR_WINDOW: "axes[].following_error_window_mm",
    c.FOLLOWING_ERROR_TIMEOUT: "axes[].following_error_timeout_ms",
    c.PRODUCER_HEARTBEAT_TIME: "monitoring.heartbeat_producer_ms",
    c.CONSUMER_HEARTBEAT_TIME: "monitoring.master_heartbeat_ms", c.QUICK_STOP_DECELERATION: "axes[].quick_stop_decel",
}
PDO_OBJECTS = range(c.RPDO_COMM, c.TPDO_MAPPING + 0x200)  # 0x1400-0x1BFF: communication and mapping


def _objects_written(steps: list[Step]) -> set[int]:
    """Indices the plan writes: SDO writes and the PDOs it maps or disables."""
    owned = {step.index for step in steps if isinstance(step, Write)}
    for step in steps:
        if isinstance(step, PdoSetup):
            comm = c.RPDO_COMM if step.kind == "RPDO" else c.TPDO_COMM
            owned |= {comm + step.number - 1, comm + 0x200 + step.number - 1}
    return owned


def _sdo_overrides_plan(index: int, value: int, owned: set[int]) -> str | None:
    """Why an ``sdo:`` entry may not write an object the bring-up writes itself: the list is
    written last, so it would silently undo the plan. 0x605A may choose another option within
    1-4 (each ends QUICK STOP ACTIVE in SWITCH ON DISABLED, so the drive never resumes a
    set-point by itself, CiA 402 §6.2.2); 5-8 would leave it in QUICK STOP ACTIVE. 0x1007 may
    give one drive its own SYNC window."""
    if index == c.QUICK_STOP_OPTION:
        if 1 <= value <= 4:
            return None
        return (f"0x605A (quick stop option) = {value} is refused: the master needs 1-4 (quick stop ends in "
                f"SWITCH ON DISABLED); 5-8 keep the drive in QUICK STOP ACTIVE, where a controlword could resume motion")
    if index not in owned or index == 0x1007:  # a per-drive SYNC window over bus.sync_window_us (docs/fieldbus.md)
        return None
    if index in PDO_OBJECTS:
        return f"0x{index:04X} is a PDO object the bring-up maps itself from the EDS; the sdo list may not change it"
    return f"0x{index:04X} is written by the bring-up from {OWNER_KEYS.get(index, 'the configuration')}; " \
        "set it there, not in the sdo list"


def _heartbeat_consumer(b: _Builder, config: MachineConfig) -> None:
    """0x1016:01 = master node id << 16 | consumer time ms (CiA 301 §7.5.2.29)."""
    mon = config.monitoring
    if mon.master_heartbeat_ms == 0:
        b.skipped.append(Skipped("0x1016:01", "monitoring.master_heartbeat_ms is 0: no master heartbeat"))
        return
    consumer_ms = mon.master_heartbeat_ms * mon.master_heartbeat_consumer_multiple
    value = config.master.node_id << 16 | consumer_ms
    if b.write("watch the master's heartbeat", c.CONSUMER_HEARTBEAT_TIME, 1, value,
               f"node {config.master.node_id}, {consumer_ms} ms", optional=True) is False:
        b.skipped[-1] = Skipped("0x1016:01", f"{b.skipped[-1].reason}: the drive does not notice a dead master")


def plan_machine(config: MachineConfig, window_counts: list[int], following_error_tpdo: bool) -> list[DrivePlan]:
    """Plans of every axis; every refusal at once (InputErrors, one line each)."""
    plans, errors = [], []
    for i in range(len(config.axes)):
        try:
            plans.append(plan_drive(config, i, window_counts[i], following_error_tpdo))
        except InputError as err:
            errors.append(err)
    if errors:
        raise InputErrors(errors)
    return plans


def cyclic_load(config: MachineConfig, plans: list[DrivePlan]) -> float:
    """Bus load of the planned cyclic frames: (SYNC + every axis' RPDOs and TPDOs + the
    drives' and the master's heartbeats per cycle) bits / (bitrate · T); see busload."""
    period_s, mon = config.cycle_period_s, config.monitoring
    bits: float = frame_bits(SYNC_DLC) + sum(frame_bits(f.dlc) for p in plans for f in p.layout.rpdos + p.layout.tpdos)
    bits += len(plans) * frame_bits(HEARTBEAT_DLC) * period_s * 1000.0 / mon.heartbeat_producer_ms
    if mon.master_heartbeat_ms:
        bits += frame_bits(HEARTBEAT_DLC) * period_s * 1000.0 / mon.master_heartbeat_ms
    return bits / (config.bus.bitrate * period_s)


def plan_within_load(config: MachineConfig, window_counts: list[int], check_load: bool = True) -> list[DrivePlan]:
    """Every axis' plan, with the following-error TPDO only where the planned frames (split
    PDOs included) still fit ``monitoring.max_bus_load``; refused when even without it they
    do not (InputError at cycle_period_ms)."""
    limit = config.monitoring.max_bus_load
    following_error = fits_following_error_tpdo(config)
    plans = plan_machine(config, window_counts, following_error)
    if following_error and cyclic_load(config, plans) > limit:
        plans = plan_machine(config, window_counts, False)
    load = cyclic_load(config, plans)
    if check_load and load > limit:
        raise InputError(config.where("cycle_period_ms"), f"bus load {load:.0%} of the planned PDOs (some drives need "
                         f"two PDOs per direction) at {config.cycle_period_s * 1000:g} ms exceeds {limit:.0%} "
                         f"(monitoring.max_bus_load): use a longer cycle, fewer axes on this bus or a higher bitrate")
    return plans


def describe_value(od: ObjectDictionary | None, index: int, subindex: int, value: int) -> str:
    """``0x1600:02 = 0x60C10120 (0x60C1:01, 32 bit)``; ``0x6060:00 = 8 (Modes of operation)``."""
    where = drive_od.name_of(index, subindex)
    is_mapping = c.RPDO_MAPPING <= index < c.RPDO_MAPPING + 0x200 or c.TPDO_MAPPING <= index < c.TPDO_MAPPING + 0x200
    if is_mapping and subindex > 0:
        return f"{where} = 0x{value:08X} ({drive_od.name_of(value >> 16, value >> 8 & 0xFF)}, {value & 0xFF} bit)"
    is_cob = (c.RPDO_COMM <= index < c.RPDO_COMM + 0x200 or c.TPDO_COMM <= index < c.TPDO_COMM + 0x200) and subindex == 1
    if is_cob or index == c.CONSUMER_HEARTBEAT_TIME:
        shown = f"0x{value:08X}"
    else:
        shown = str(value)
    var = drive_od.find(od, index, subindex) if od is not None else None
    return f"{where} = {shown}" + (f" ({var.name})" if var is not None and var.name else "")


__all__ = ["AxisPdoLayout", "DrivePlan", "Field", "PdoFrame", "PdoSetup", "ReadBack", "Skipped", "Write",
           "describe_value", "mapping_entry", "offered_modes", "plan_drive", "plan_machine", "plan_within_load", "rpdo_packer"]
