"""A drive's object dictionary (EDS/DCF, CiA 306) as canopen reads it, and the questions
asked of it before a write: does the object exist, may it be written, is the value in range.

Shared by the configuration (the ``sdo:`` list is checked at load time, as Lely's dcfgen
does) and the master's bring-up plan; the simulator reads its EDS on its own.
"""

from __future__ import annotations

import functools
from pathlib import Path

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, ObjectDictionary, datatypes

from nurbsmotion import data

# YAML ``type:`` names of the CiA 301 integer data types (§7.1.4.3) and their codes.
TYPE_CODES: dict[str, int] = {
    "bool": datatypes.BOOLEAN, "int8": datatypes.INTEGER8, "int16": datatypes.INTEGER16,
    "int32": datatypes.INTEGER32, "int64": datatypes.INTEGER64, "uint8": datatypes.UNSIGNED8,
    "uint16": datatypes.UNSIGNED16, "uint32": datatypes.UNSIGNED32, "uint64": datatypes.UNSIGNED64,
}
TYPE_NAMES = {code: name for name, code in TYPE_CODES.items()}
_BITS = {datatypes.BOOLEAN: 1, datatypes.INTEGER8: 8, datatypes.INTEGER16: 16, datatypes.INTEGER32: 32,
         datatypes.INTEGER64: 64, datatypes.UNSIGNED8: 8, datatypes.UNSIGNED16: 16, datatypes.UNSIGNED32: 32,
         datatypes.UNSIGNED64: 64, datatypes.REAL32: 32, datatypes.REAL64: 64}


class DescriptionError(Exception):
    """An EDS/DCF that cannot be read; ``str()`` is one line."""


@functools.lru_cache(maxsize=64)
def _load(path: str, node_id: int, mtime_ns: int) -> ObjectDictionary:
    return canopen.import_od(path, node_id)


def default_eds_path() -> str:
    """The packaged description of nurbsmotion's simulated servo (eds/nurbsmotion-servo.eds)."""
    return str(data.path("nurbsmotion-servo.eds"))


def load_description(path: str | Path, node_id: int) -> ObjectDictionary:
    """canopen's ``import_od`` of an EDS/DCF for ``node_id`` (cached per file version)."""
    p = Path(path)
    try:
        return _load(str(p), node_id, p.stat().st_mtime_ns)
    except OSError as err:
        raise DescriptionError(f"cannot read {p.name}: {err.strerror or err}") from None
    except Exception as err:  # noqa: BLE001 - configparser, canopen and int() raise many kinds
        text = " ".join(str(err).split())[:200]
        raise DescriptionError(f"{p.name} is not a readable EDS/DCF: {type(err).__name__}: {text}") from None


def find(od: ObjectDictionary, index: int, subindex: int = 0) -> ODVariable | None:
    """The variable (index, subindex) the file really describes, else None.

    canopen's ODArray invents sub-entries 1..255 from its first one on access; only the
    sub-entries the file lists count here. A VAR is addressed with subindex 0."""
    obj = od.get(index) if index in od.indices else None
    if obj is None:
        return None
    if isinstance(obj, (ODRecord, ODArray)):
        return obj.subindices.get(subindex)
    return obj if subindex == 0 else None


def has(od: ObjectDictionary, index: int, subindex: int = 0) -> bool:
    return find(od, index, subindex) is not None


def sub_count(od: ObjectDictionary, index: int) -> int:
    """Sub-entries 1..n the file lists for a RECORD/ARRAY (0 for a VAR or a missing object)."""
    obj = od.get(index) if index in od.indices else None
    if not isinstance(obj, (ODRecord, ODArray)):
        return 0
    return sum(1 for s in obj.subindices if s > 0)


def bits(var: ODVariable) -> int:
    return _BITS.get(var.data_type or 0, 0)


def type_name(var: ODVariable) -> str:
    return TYPE_NAMES.get(var.data_type or 0, f"type 0x{var.data_type or 0:04X}")


def type_range(var: ODVariable) -> tuple[int, int] | None:
    """Values the data type can hold (integer types only)."""
    n = bits(var)
    if var.data_type in datatypes.SIGNED_TYPES and n:
        return -(1 << (n - 1)), (1 << (n - 1)) - 1
    if var.data_type in datatypes.UNSIGNED_TYPES or var.data_type == datatypes.BOOLEAN:
        return 0, (1 << n) - 1
    return None


def allowed_range(var: ODVariable) -> tuple[int, int] | None:
    """The data type's range narrowed by the file's LowLimit/HighLimit."""
    full = type_range(var)
    if full is None:
        return None
    low = full[0] if var.min is None else max(full[0], var.min)
    high = full[1] if var.max is None else min(full[1], var.max)
    return low, high


def name_of(index: int, subindex: int) -> str:
    return f"0x{index:04X}:{subindex:02X}"


def write_problem(var: ODVariable, value: int) -> str | None:
    """Why the drive would refuse an SDO write of ``value``, or None (CiA 301 access types
    rw/wo/rww/rwr may be written; ro/const may not; LowLimit..HighLimit and the type's range)."""
    if not var.writable:
        return f"is read-only (AccessType={var.access_type})"
    span = allowed_range(var)
    if span is None:
        return f"has data type {type_name(var)}, which only integer values are written to"
    low, high = span
    if not low <= value <= high:
        limits = "LowLimit/HighLimit" if (var.min is not None or var.max is not None) else type_name(var)
        return f"allows {low}..{high} ({limits}), not {value}"
    return None
