"""PDO layout used by the master and the SDO writes that configure a drive for it.

RPDO1 (0x200+node, synchronous): controlword 0x6040 (u16) + set-point (i32): 0x60C1:01 in
IP mode, 0x607A in CSP mode. TPDO1 (0x180+node, every SYNC): statusword 0x6041 (u16) +
position actual 0x6064 (i32). Optional TPDO2 (0x280+node, every SYNC): following error
actual 0x60F4 (i32). All other PDOs are disabled (COB-ID bit 31) so they load no bus.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from nurbsmotion import cia402 as c

RPDO_FORMAT = struct.Struct("<Hi")  # controlword, set-point
TPDO1_FORMAT = struct.Struct("<Hi")  # statusword, position actual
TPDO2_FORMAT = struct.Struct("<i")  # following error actual

ABORT_OBJECT_DOES_NOT_EXIST = 0x0602_0000
ABORT_SUBINDEX_DOES_NOT_EXIST = 0x0609_0011


@dataclass(frozen=True)
class SdoWrite:
    """One expedited SDO download: ``value`` packed with ``fmt`` into (index, subindex)."""

    step: str  # names the bring-up step in error messages
    index: int
    subindex: int
    fmt: str  # struct format, little endian
    value: int
    optional: bool = False  # an abort 'object does not exist' is ignored

    def data(self) -> bytes:
        return struct.pack(self.fmt, self.value)


def mapping_entry(index: int, subindex: int, bits: int) -> int:
    """PDO mapping entry (CiA 301): index << 16 | subindex << 8 | length in bits."""
    return index << 16 | subindex << 8 | bits


def interpolation_period(period_s: float) -> tuple[int, int]:
    """0x60C2 (value u8, exponent i8) with value·10^exponent = period, exact to 1 µs."""
    for exponent in range(-3, -7, -1):
        value = period_s / 10.0**exponent
        if abs(value - round(value)) < 1e-6 and 0 < round(value) <= 255:
            return int(round(value)), exponent
    raise ValueError(f"cycle period {period_s} s has no 0x60C2 representation")


def _pdo_writes(kind: str, number: int, node_id: int, entries: list[int] | None) -> list[SdoWrite]:
    """Disable, remap and (if ``entries``) re-enable one PDO, in the order CiA 301 requires."""
    comm = (c.RPDO_COMM if kind == "RPDO" else c.TPDO_COMM) + number - 1
    mapping = (c.RPDO_MAPPING if kind == "RPDO" else c.TPDO_MAPPING) + number - 1
    cob_id = (c.COB_RPDO if kind == "RPDO" else c.COB_TPDO)[number - 1] + node_id
    step = f"configure {kind}{number}"
    if entries is None:  # not used: disable; a drive without this PDO is fine
        return [SdoWrite(step, comm, 1, "<I", c.PDO_COB_ID_INVALID | cob_id, optional=True)]
    writes = [SdoWrite(step, comm, 1, "<I", c.PDO_COB_ID_INVALID | cob_id),
              SdoWrite(step, comm, 2, "<B", c.TRANSMISSION_SYNC_EVERY),
              SdoWrite(step, mapping, 0, "<B", 0)]
    writes += [SdoWrite(step, mapping, i + 1, "<I", e) for i, e in enumerate(entries)]
    writes += [SdoWrite(step, mapping, 0, "<B", len(entries)), SdoWrite(step, comm, 1, "<I", cob_id)]
    return writes


def drive_configuration(node_id: int, mode: c.Mode, cycle_period_s: float, heartbeat_producer_ms: int,
                        following_error_window_counts: int, following_error_timeout_ms: int,
                        following_error_tpdo: bool, quick_stop_decel_counts_s2: int | None = None) -> list[SdoWrite]:
    """Every SDO write of bring-up for one drive, in order (done in NMT PRE-OPERATIONAL)."""
    ip = mode == c.Mode.INTERPOLATED_POSITION
    setpoint = mapping_entry(c.IP_DATA_RECORD, 1, 32) if ip else mapping_entry(c.TARGET_POSITION, 0, 32)
    writes = [SdoWrite("set mode", c.MODES_OF_OPERATION, 0, "<b", int(mode))]
    if ip:
        value, exponent = interpolation_period(cycle_period_s)
        writes += [SdoWrite("set interpolation sub-mode", c.IP_SUB_MODE, 0, "<h", 0),
                   SdoWrite("set interpolation period", c.IP_TIME_PERIOD, 1, "<B", value),
                   SdoWrite("set interpolation period", c.IP_TIME_PERIOD, 2, "<b", exponent)]
    writes.append(SdoWrite("set cycle period", c.COMM_CYCLE_PERIOD, 0, "<I", round(cycle_period_s * 1e6),
                           optional=True))
    writes += _pdo_writes("RPDO", 1, node_id, [mapping_entry(c.CONTROLWORD, 0, 16), setpoint])
    for n in (2, 3, 4):
        writes += _pdo_writes("RPDO", n, node_id, None)
    writes += _pdo_writes("TPDO", 1, node_id, [mapping_entry(c.STATUSWORD, 0, 16), mapping_entry(c.POSITION_ACTUAL, 0, 32)])
    writes += _pdo_writes("TPDO", 2, node_id, [mapping_entry(c.FOLLOWING_ERROR_ACTUAL, 0, 32)] if following_error_tpdo else None)
    for n in (3, 4):
        writes += _pdo_writes("TPDO", n, node_id, None)
    writes += [SdoWrite("set following error window", c.FOLLOWING_ERROR_WINDOW, 0, "<I", following_error_window_counts),
               SdoWrite("set following error time-out", c.FOLLOWING_ERROR_TIMEOUT, 0, "<H", following_error_timeout_ms),
               SdoWrite("set heartbeat producer", c.PRODUCER_HEARTBEAT_TIME, 0, "<H", heartbeat_producer_ms)]
    if quick_stop_decel_counts_s2 is not None:  # the drive's own quick-stop ramp: within the axis' a_max
        writes.append(SdoWrite("set quick stop deceleration", c.QUICK_STOP_DECELERATION, 0, "<I",
                               min(max(quick_stop_decel_counts_s2, 1), 2**32 - 1), optional=True))
    return writes


def cycles_of_ms(ms: float, cycle_period_s: float) -> int:
    """Whole cycles covering ``ms`` milliseconds (at least 1)."""
    return max(1, math.ceil(ms / 1000.0 / cycle_period_s - 1e-9))
