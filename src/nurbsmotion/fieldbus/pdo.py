"""PDO encodings shared by bring-up and the cycle loop (CiA 301 §7.4.7, CiA 402 §8).

The standard layout: RPDO1 = controlword 0x6040 (u16) + set-point (i32: 0x60C1:01 in IP,
0x607A in CSP); TPDO1 = statusword 0x6041 (u16) + position actual 0x6064 (i32); TPDO2 =
following error actual 0x60F4 (i32) when the drive has it and the bus load allows. A drive
whose PDOs map fewer entries gets them split (see ``bringup_plan.AxisPdoLayout``).
"""

from __future__ import annotations

import math
import struct

RPDO_FORMAT = struct.Struct("<Hi")  # controlword, set-point (the standard one-frame layout)
TPDO1_FORMAT = struct.Struct("<Hi")  # statusword, position actual
TPDO2_FORMAT = struct.Struct("<i")  # following error actual


def mapping_entry(index: int, subindex: int, bits: int) -> int:
    """PDO mapping entry (CiA 301): index << 16 | subindex << 8 | length in bits."""
    return index << 16 | subindex << 8 | bits


def interpolation_period(period_s: float, exponent: int | None = None) -> tuple[int, int]:
    """0x60C2 (value u8, exponent i8) with value·10^exponent = period, exact to 1 µs.

    ``exponent`` given (a drive whose 0x60C2:02 is read-only): the value for that exponent."""
    for exp in ((exponent,) if exponent is not None else range(-3, -7, -1)):
        value = period_s / 10.0**exp
        if abs(value - round(value)) < 1e-6 and 0 < round(value) <= 255:
            return int(round(value)), exp
    fixed = f" with the drive's fixed exponent {exponent}" if exponent is not None else ""
    raise ValueError(f"cycle period {period_s * 1000:g} ms has no 0x60C2 representation{fixed}")


def cycles_of_ms(ms: float, cycle_period_s: float) -> int:
    """Whole cycles covering ``ms`` milliseconds (at least 1)."""
    return max(1, math.ceil(ms / 1000.0 / cycle_period_s - 1e-9))
