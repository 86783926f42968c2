"""A drive's object dictionary (EDS/DCF, CiA 306) as canopen reads it, and the questions
asked of it before a write: does the object exist, may it be written, is the value in range.

Shared by the configuration (the ``sdo:`` list is checked at load time, as Lely's dcfgen
does) and the master's bring-up plan; the simulator reads its EDS on its own.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING

from nurbsmotion import data

if TYPE_CHECKING:  # canopen (and python-can under it) is imported only when a file is read
    from canopen.objectdictionary import ODVariable, ObjectDictionary


class DataType:
    """CiA 301 data type codes (the object dictionary's data type entries 0x0001..0x001B),
    as canopen.objectdictionary.datatypes has them: the configuration's ``type:`` names need
    them, and importing canopen (python-can, asyncio, ...) for a few numbers would cost every
    command that imports the configuration (``plan`` too) about 0.1 s of CPU."""

    BOOLEAN, INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32, REAL32 = 1, 2, 3, 4, 5, 6, 7, 8
    INTEGER24, REAL64, INTEGER40, INTEGER48, INTEGER56, INTEGER64 = 0x10, 0x11, 0x12, 0x13, 0x14, 0x15
    UNSIGNED24, UNSIGNED40, UNSIGNED48, UNSIGNED56, UNSIGNED64 = 0x16, 0x18, 0x19, 0x1A, 0x1B
    SIGNED = (INTEGER8, INTEGER16, INTEGER24, INTEGER32, INTEGER40, INTEGER48, INTEGER56, INTEGER64)
    UNSIGNED = (UNSIGNED8, UNSIGNED16, UNSIGNED24, UNSIGNED32, UNSIGNED40, UNSIGNED48, UNSIGNED56, UNSIGNED64)


# YAML ``type:`` names of the CiA 301 integer data types and their codes.
TYPE_CODES: dict[str, int] = {
    "bool": DataType.BOOLEAN, "int8": DataType.INTEGER8, "int16": DataType.INTEGER16,
    "int32": DataType.INTEGER32, "int64": DataType.INTEGER64, "uint8": DataType.UNSIGNED8,
    "uint16": DataType.UNSIGNED16, "uint32": DataType.UNSIGNED32, "uint64": DataType.UNSIGNED64,
}
TYPE_NAMES = {code: name for name, code in TYPE_CODES.items()}
_BITS = {DataType.BOOLEAN: 1, DataType.INTEGER8: 8, DataType.INTEGER16: 16, DataType.INTEGER32: 32,
         DataType.INTEGER64: 64, DataType.UNSIGNED8: 8, DataType.UNSIGNED16: 16, DataType.UNSIGNED32: 32,
         DataType.UNSIGNED64: 64, DataType.REAL32: 32, DataType.REAL64: 64}


class DescriptionError(Exception):
    """An EDS/DCF that cannot be read; ``str()`` is one line."""


@functools.lru_cache(maxsize=64)
def _load(path: str, node_id: int, mtime_ns: int) -> ObjectDictionary:
    import canopen

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
    from canopen.objectdictionary import ODArray, ODRecord

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
    from canopen.objectdictionary import ODArray, ODRecord

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
    if var.data_type in DataType.SIGNED and n:
        return -(1 << (n - 1)), (1 << (n - 1)) - 1
    if var.data_type in DataType.UNSIGNED or var.data_type == DataType.BOOLEAN:
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
