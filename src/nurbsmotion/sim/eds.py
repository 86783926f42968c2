"""What a drive description (EDS/DCF) says about its objects, as the simulated drive enforces it.

A simulated drive can be built from any vendor EDS (canopen's ``import_od``). The EDS is the
whole truth about the drive: an object it lacks does not exist, an entry without a value
starts at 0 (CiA 306 leaves it to the device; a master must write what it needs), access
types and LowLimit/HighLimit are checked on every SDO write, and 0x6502 lists the modes
0x6060 accepts.
"""

from __future__ import annotations

from pathlib import Path

from canopen import objectdictionary as od_types
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.sdo import SdoAbortedError

from nurbsmotion.can import cia402 as c

EDS_NAME = "nurbsmotion-servo.eds"

ABORT_VALUE_INVALID = 0x06090030  # value range of parameter exceeded (only for write access)
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032

# 0x6502 bit -> mode of operation (CiA 402-2, 'supported drive modes')
MODE_OF_SUPPORTED_BIT = {0: 1, 1: 2, 2: 3, 3: 4, 5: 6, 6: 7, 7: 8, 8: 9, 9: 10}
# Modes a drive whose EDS gives no 0x6502 value may have: the standard ones.
STANDARD_MODES = frozenset(MODE_OF_SUPPORTED_BIT.values())


def default_eds_path() -> Path:
    """Path of eds/nurbsmotion-servo.eds: the repository's eds/ dir (src layout), else a copy
    installed next to this module."""
    here = Path(__file__).resolve().parent
    candidates = (here.parents[2] / "eds" / EDS_NAME, here / EDS_NAME)
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(f"{EDS_NAME} not found in {', '.join(str(p.parent) for p in candidates)}")


def find_variable(od: ObjectDictionary, index: int, subindex: int) -> ODVariable | None:
    """The EDS entry of (index, subindex), None if the drive has no such object."""
    if index not in od:
        return None
    obj = od[index]
    if isinstance(obj, ODVariable):
        return obj if subindex == 0 else None
    return obj[subindex] if subindex in obj.subindices else None


def has_object(od: ObjectDictionary, index: int, subindex: int = 0) -> bool:
    return find_variable(od, index, subindex) is not None


def initial_data(var: ODVariable) -> bytes:
    """An entry's value before anything was written: ParameterValue (DCF), else DefaultValue,
    else 0 (the nearest limit if the EDS's own LowLimit/HighLimit exclude 0: EPOS2 0x2212:01
    >= 16). Strings and domains without a value read as one NUL byte (an SDO upload cannot
    carry 0 bytes; a real drive never answers 'no data' for its name)."""
    value: int | float | str | bytes | None = var.value if var.value is not None else var.default
    if var.data_type not in var.STRUCT_TYPES:
        data = var.encode_raw(value) if value is not None else b""
        return data or b"\x00"
    if value is None:
        low, high = limits(var)
        value = 0
        if low is not None and low > 0:
            value = low
        elif high is not None and high < 0:
            value = high
        if var.data_type in (od_types.REAL32, od_types.REAL64):
            value = float(value)
    if not isinstance(value, (int, float)):  # a numeric type holds a number (canopen parsed the EDS)
        raise TypeError(f"0x{var.index:04X}:{var.subindex:02X}: {value!r} is not a number")
    return var.encode_raw(_as_signed(var, value))


def _as_signed(var: ODVariable, value: int | float) -> int | float:
    """A signed default written in hex as its two's complement (EPOS2: 0x60C0 = 0xFFFF, i.e.
    -1; canopen reads it unsigned)."""
    if var.data_type in od_types.SIGNED_TYPES and isinstance(value, int):
        bits = len(var)
        if 2 ** (bits - 1) <= value < 2**bits:
            return value - 2**bits
    return value


def limits(var: ODVariable) -> tuple[int | float | None, int | float | None]:
    """(LowLimit, HighLimit) of an entry; (None, None) for an inverted range, which some
    EDS files write (Faulhaber 0x6061: 0..0xFF on an INTEGER8 reads as 0..-1)."""
    low, high = var.min, var.max
    if low is not None and high is not None and low > high:
        return None, None
    return low, high


def check_range(var: ODVariable, value: object) -> None:
    """LowLimit/HighLimit of the EDS (CiA 301 aborts 0x06090032 too low, 0x06090031 too high)."""
    if not isinstance(value, (int, float)):
        return
    low, high = limits(var)
    if low is not None and value < low:
        raise SdoAbortedError(ABORT_VALUE_TOO_LOW)
    if high is not None and value > high:
        raise SdoAbortedError(ABORT_VALUE_TOO_HIGH)


def supported_modes(supported_bits: int, mode_var: ODVariable | None = None) -> frozenset[int]:
    """Modes 0x6060 accepts: those of the 0x6502 value; when the EDS gives none (0: the
    description does not say), the standard modes within 0x6060's LowLimit/HighLimit."""
    if supported_bits:
        return frozenset(mode for bit, mode in MODE_OF_SUPPORTED_BIT.items() if supported_bits >> bit & 1)
    low, high = limits(mode_var) if mode_var is not None else (None, None)
    return frozenset(m for m in STANDARD_MODES if (low is None or m >= low) and (high is None or m <= high))


def cycle_period_source(od: ObjectDictionary) -> int | None:
    """The object a drive takes its IP/CSP cycle from: 0x60C2 when the EDS has it (EPOS4,
    AKD, Elmo, Nanotec interpolate over 0x60C2 in CSP too), else 0x1006; None if neither
    exists (the drive then locks onto the measured SYNC interval)."""
    if has_object(od, c.IP_TIME_PERIOD, 1):
        return c.IP_TIME_PERIOD
    if has_object(od, c.COMM_CYCLE_PERIOD):
        return c.COMM_CYCLE_PERIOD
    return None
