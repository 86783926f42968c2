"""PDO layouts of a simulated drive, computed once when the master (re)maps a PDO.

A mapping entry (0x16xx / 0x1Axx sub n, CiA 301) is ``index << 16 | subindex << 8 | bits``.
A layout turns the entries into one ``struct.Struct`` so that a frame is decoded or encoded
with a single ``unpack_from`` / ``pack_into`` per SYNC.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from canopen import objectdictionary as od_types
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord
from canopen.sdo import SdoAbortedError

from nurbsmotion.sim.eds import ABORT_VALUE_INVALID, find_variable

ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH_EXCEEDED = 0x06040042
ABORT_DEVICE_STATE = 0x08000022
COB_ID_INVALID_BIT = 0x8000_0000
COB_ID_EXTENDED_BIT = 0x2000_0000
MAX_PDO_BITS = 64
MAX_PDO_ENTRIES = 8  # CAN classic: 8 bytes, at least 8 bits per entry

_STRUCT_CODE = {
    od_types.BOOLEAN: "?",
    od_types.INTEGER8: "b",
    od_types.UNSIGNED8: "B",
    od_types.INTEGER16: "h",
    od_types.UNSIGNED16: "H",
    od_types.INTEGER32: "i",
    od_types.UNSIGNED32: "I",
    od_types.INTEGER64: "q",
    od_types.UNSIGNED64: "Q",
    od_types.REAL32: "f",
    od_types.REAL64: "d",
}
# CiA 301 dummy entries (RPDO only): index = data type, nothing is written.
_DUMMY_BITS = {0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}


def split_entry(entry: int) -> tuple[int, int, int]:
    """(index, subindex, bits) of a mapping entry."""
    return (entry >> 16) & 0xFFFF, (entry >> 8) & 0xFF, entry & 0xFF


def check_entry(od: ObjectDictionary, entry: int, receive: bool) -> None:
    """Raise the SDO abort a drive answers when ``entry`` cannot be mapped (0 = empty entry)."""
    if entry == 0:
        return
    index, subindex, bits = split_entry(entry)
    if receive and index in _DUMMY_BITS and subindex == 0:
        if bits != _DUMMY_BITS[index]:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        return
    var = find_variable(od, index, subindex)
    if var is None or not var.pdo_mappable or var.data_type not in _STRUCT_CODE:
        raise SdoAbortedError(ABORT_NOT_MAPPABLE)
    if (receive and not var.writable) or (not receive and not var.readable) or len(var) != bits:
        raise SdoAbortedError(ABORT_NOT_MAPPABLE)


def check_entries(od: ObjectDictionary, entries: list[int], receive: bool) -> None:
    """Check a whole mapping before it is activated (writing the entry count)."""
    if len(entries) > MAX_PDO_ENTRIES:
        raise SdoAbortedError(ABORT_PDO_LENGTH_EXCEEDED)
    for entry in entries:
        if entry == 0:  # counted but never written: object 0x0000:00 cannot be mapped
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        check_entry(od, entry, receive)
    if sum(split_entry(e)[2] for e in entries) > MAX_PDO_BITS:
        raise SdoAbortedError(ABORT_PDO_LENGTH_EXCEEDED)


@dataclass
class PdoLayout:
    """One PDO as the drive currently sees it."""

    number: int  # 1..512
    cob_id: int  # 11-bit CAN id
    enabled: bool
    transmission_type: int
    keys: list[tuple[int, int]] = field(default_factory=list)  # mapped (index, subindex); dummies skipped
    codec: struct.Struct = field(default_factory=lambda: struct.Struct("<"))

    @property
    def size(self) -> int:
        return self.codec.size

    @property
    def synchronous(self) -> bool:
        """Transmission types 0..240 are synchronous (CiA 301)."""
        return self.transmission_type <= 240


# CiA 301 7.3.5: CAN ids no PDO may use (NMT, SYNC/EMCY group, TIME, SDO, heartbeat, LSS, ...)
RESTRICTED_CAN_IDS = ((0x000, 0x07F), (0x101, 0x180), (0x581, 0x5FF), (0x601, 0x67F), (0x6E0, 0x6FF), (0x701, 0x7FF))


def restricted_can_id(can_id: int) -> bool:
    return any(low <= can_id <= high for low, high in RESTRICTED_CAN_IDS)


def build_layout(od: ObjectDictionary, number: int, cob_id_value: int, transmission_type: int, entries: list[int]) -> PdoLayout:
    """Layout of PDO ``number`` from its communication and mapping parameter values."""
    fmt = "<"
    keys: list[tuple[int, int]] = []
    for entry in entries:
        if entry == 0:
            continue
        index, subindex, bits = split_entry(entry)
        var = find_variable(od, index, subindex)
        if var is None or var.data_type not in _STRUCT_CODE:  # dummy entry (or a type not simulated): skip its bytes
            fmt += f"{(bits + 7) // 8}x"
            continue
        fmt += _STRUCT_CODE[var.data_type]
        keys.append((index, subindex))
    return PdoLayout(
        number=number,
        cob_id=cob_id_value & 0x7FF,
        enabled=not cob_id_value & COB_ID_INVALID_BIT and not restricted_can_id(cob_id_value & 0x7FF),
        transmission_type=transmission_type,
        keys=keys,
        codec=struct.Struct(fmt),
    )


Reader = Callable[[int, int], int]  # (index, subindex) -> current value in the drive


RPDO_COMM_RANGE = range(0x1400, 0x1600)
RPDO_MAPPING_RANGE = range(0x1600, 0x1800)
TPDO_COMM_RANGE = range(0x1800, 0x1A00)
TPDO_MAPPING_RANGE = range(0x1A00, 0x1C00)
MAPPING_OFFSET = 0x200  # 0x16xx -> 0x14xx, 0x1Axx -> 0x18xx


def is_pdo_parameter(index: int) -> bool:
    """RPDO/TPDO communication (0x1400.., 0x1800..) or mapping (0x1600.., 0x1A00..) parameter."""
    return 0x1400 <= index < 0x1C00


def declared_entries(od: ObjectDictionary, map_index: int) -> int:
    """How many mapping entries the drive's EDS declares for a PDO (IDM: 1, most: 8)."""
    entry = od[map_index]
    return sum(1 for sub in entry.subindices if sub > 0) if isinstance(entry, (ODRecord, ODArray)) else 0


def check_parameter_write(od: ObjectDictionary, read: Reader, index: int, subindex: int, value: int) -> None:
    """Raise the SDO abort for a write to a PDO parameter that CiA 301 does not allow."""
    if index in RPDO_COMM_RANGE or index in TPDO_COMM_RANGE:
        check_communication_write(read, index, subindex, value)
    elif index in RPDO_MAPPING_RANGE or index in TPDO_MAPPING_RANGE:
        check_mapping_write(od, read, index, subindex, value)


def check_communication_write(read: Reader, index: int, subindex: int, value: int) -> None:
    """The CAN id of a valid PDO cannot change (disable it with bit 31 first); 11-bit ids
    outside the restricted ones only; transmission types 241..251 are reserved."""
    if subindex == 1:
        current = read(index, 1)
        if value & COB_ID_EXTENDED_BIT or (not value & COB_ID_INVALID_BIT and restricted_can_id(value & 0x7FF)):
            raise SdoAbortedError(ABORT_VALUE_INVALID)
        both_valid = not current & COB_ID_INVALID_BIT and not value & COB_ID_INVALID_BIT
        if both_valid and (current & 0x7FF) != (value & 0x7FF):
            raise SdoAbortedError(ABORT_VALUE_INVALID)
    elif subindex == 2 and 241 <= value <= 251:
        raise SdoAbortedError(ABORT_VALUE_INVALID)


def check_mapping_write(od: ObjectDictionary, read: Reader, index: int, subindex: int, value: int) -> None:
    """CiA 301 mapping procedure: PDO disabled, count 0, entries, count (checks them all:
    mappable, at most the entries the EDS declares, at most 64 bits)."""
    receive = index in RPDO_MAPPING_RANGE
    comm = index - MAPPING_OFFSET
    if find_variable(od, comm, 1) is not None and not read(comm, 1) & COB_ID_INVALID_BIT:
        raise SdoAbortedError(ABORT_DEVICE_STATE)
    if subindex == 0:
        if value > declared_entries(od, index):
            raise SdoAbortedError(ABORT_PDO_LENGTH_EXCEEDED)
        check_entries(od, [read(index, n) for n in range(1, value + 1)], receive)
    else:
        if read(index, 0) != 0:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        check_entry(od, value, receive)
