"""Write eds/nurbsmotion-servo.eds: a generic CiA-402 servo drive (PV, homing, IP, CSP, CSV), CiA 306 format.

The EDS is generated so that its ~60 sections stay consistent (sub-counts, PDO defaults).
Run ``python eds/generate.py`` after editing the tables below and commit both files.
"""

from __future__ import annotations

from pathlib import Path

INT8, INT16, INT32, UINT8, UINT16, UINT32, VISIBLE_STRING = 0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x9
VAR, ARRAY, RECORD = 0x7, 0x8, 0x9

# (name, data type, access, default, pdo-mappable)
Sub = tuple[str, int, str, str, bool]


def var(name: str, dtype: int, access: str, default: str = "0", pdo: bool = False) -> Sub:
    return (name, dtype, access, default, pdo)


def pdo_comm(kind: str, n: int, cob_base: int, enabled: bool) -> tuple[str, int, list[Sub]]:
    cob = f"$NODEID+0x{cob_base:X}" if enabled else f"0x{0x8000_0000 + cob_base:X}+$NODEID"
    subs = [var("COB-ID used by PDO", UINT32, "rw", cob), var("Transmission type", UINT8, "rw", "1")]
    if kind == "TPDO":
        subs += [var("Inhibit time", UINT16, "rw"), None, var("Event timer", UINT16, "rw"), var("SYNC start value", UINT8, "rw")]
    else:
        subs += [None, None, var("Event timer", UINT16, "rw")]
    return (f"{kind}{n} communication parameter", RECORD, subs)


def pdo_map(kind: str, n: int, entries: list[int]) -> tuple[str, int, list[Sub]]:
    subs = [var(f"Mapped object {i}", UINT32, "rw", f"0x{entries[i - 1]:08X}" if i <= len(entries) else "0") for i in range(1, 9)]
    return (f"{kind}{n} mapping parameter", RECORD, subs)


CW, SW = 0x60400010, 0x60410010
TARGET, IP_SETPOINT, ACTUAL, FOLLOW, MODE, MODE_DISPLAY = 0x607A0020, 0x60C10120, 0x60640020, 0x60F40020, 0x60600008, 0x60610008

# RPDO1 controlword + CSP target, RPDO2 controlword + IP set-point, TPDO1 statusword + actual.
RPDO_DEFAULT = {1: ([CW, TARGET], True), 2: ([CW, IP_SETPOINT], True), 3: ([MODE], False), 4: ([], False)}
TPDO_DEFAULT = {1: ([SW, ACTUAL], True), 2: ([SW, FOLLOW], False), 3: ([MODE_DISPLAY], False), 4: ([], False)}

OBJECTS: dict[int, tuple[str, int, object]] = {
    0x1000: ("Device type", VAR, var("", UINT32, "ro", "0x00020192")),
    0x1001: ("Error register", VAR, var("", UINT8, "ro")),
    0x1003: ("Pre-defined error field", ARRAY, [var(f"Standard error field {i}", UINT32, "ro") for i in range(1, 9)]),
    0x1005: ("COB-ID SYNC message", VAR, var("", UINT32, "rw", "0x00000080")),
    0x1008: ("Manufacturer device name", VAR, var("", VISIBLE_STRING, "const", "nurbsmotion simulated servo")),
    0x100A: ("Manufacturer software version", VAR, var("", VISIBLE_STRING, "const", "1.0")),
    0x1006: ("Communication cycle period", VAR, var("", UINT32, "rw", "1000")),
    0x1007: ("Synchronous window length", VAR, var("", UINT32, "rw", "0")),
    0x1014: ("COB-ID EMCY", VAR, var("", UINT32, "rw", "$NODEID+0x80")),
    0x1016: ("Consumer heartbeat time", ARRAY, [var(f"Consumer heartbeat time {i}", UINT32, "rw") for i in range(1, 5)]),
    0x1017: ("Producer heartbeat time", VAR, var("", UINT16, "rw", "100")),
    0x1018: ("Identity object", RECORD, [
        var("Vendor-ID", UINT32, "ro", "0x00000000"),
        var("Product code", UINT32, "ro", "0x4E4D0402"),
        var("Revision number", UINT32, "ro", "0x00010000"),
        var("Serial number", UINT32, "ro", "$NODEID+0"),
    ]),
}
for n, (entries, on) in RPDO_DEFAULT.items():
    OBJECTS[0x1400 + n - 1] = pdo_comm("RPDO", n, (0x200, 0x300, 0x400, 0x500)[n - 1], on)
    OBJECTS[0x1600 + n - 1] = pdo_map("RPDO", n, entries)
for n, (entries, on) in TPDO_DEFAULT.items():
    OBJECTS[0x1800 + n - 1] = pdo_comm("TPDO", n, (0x180, 0x280, 0x380, 0x480)[n - 1], on)
    OBJECTS[0x1A00 + n - 1] = pdo_map("TPDO", n, entries)
OBJECTS.update({
    0x603F: ("Error code", VAR, var("", UINT16, "ro", "0", True)),
    0x6040: ("Controlword", VAR, var("", UINT16, "rww", "0", True)),
    0x6041: ("Statusword", VAR, var("", UINT16, "ro", "0", True)),
    0x605A: ("Quick stop option code", VAR, var("", INT16, "rw", "2")),
    0x6060: ("Modes of operation", VAR, var("", INT8, "rww", "8", True)),
    0x6061: ("Modes of operation display", VAR, var("", INT8, "ro", "8", True)),
    0x6064: ("Position actual value", VAR, var("", INT32, "ro", "0", True)),
    0x606C: ("Velocity actual value", VAR, var("", INT32, "ro", "0", True)),
    0x606D: ("Velocity window", VAR, var("", UINT16, "rw", "100")),
    0x606E: ("Velocity window time", VAR, var("", UINT16, "rw", "10")),
    0x6065: ("Following error window", VAR, var("", UINT32, "rw", "10000")),
    0x6066: ("Following error time out", VAR, var("", UINT16, "rw", "20")),
    0x607A: ("Target position", VAR, var("", INT32, "rww", "0", True)),
    0x607D: ("Software position limit", ARRAY, [var("Min position limit", INT32, "rw"), var("Max position limit", INT32, "rw")]),
    0x607C: ("Home offset", VAR, var("", INT32, "rw", "0")),
    0x6098: ("Homing method", VAR, var("", INT8, "rw", "0")),
    0x6099: ("Homing speeds", ARRAY, [var("Speed during search for switch", UINT32, "rw"),
                                      var("Speed during search for zero", UINT32, "rw")]),
    0x609A: ("Homing acceleration", VAR, var("", UINT32, "rw", "0")),
    0x6083: ("Profile acceleration", VAR, var("", UINT32, "rw", "1000000")),
    0x6084: ("Profile deceleration", VAR, var("", UINT32, "rw", "1000000")),
    0x6085: ("Quick stop deceleration", VAR, var("", UINT32, "rw", "10000000")),
    0x60C0: ("Interpolation sub mode select", VAR, var("", INT16, "rw", "0")),
    0x60C1: ("Interpolation data record", ARRAY, [var("Interpolation data record 1", INT32, "rww", "0", True)]),
    0x60C2: ("Interpolation time period", RECORD, [var("Interpolation time period value", UINT8, "rw", "1"), var("Interpolation time index", INT8, "rw", "-3")]),
    0x60C4: ("Interpolation data configuration", RECORD, [
        var("Maximum buffer size", UINT32, "ro", "1"),
        var("Actual buffer size", UINT32, "rw", "1"),
        var("Buffer organization", UINT8, "rw", "0"),
        var("Buffer position", UINT16, "rw", "1"),
        var("Size of data record", UINT8, "rw", "1"),
        var("Buffer clear", UINT8, "rw", "0"),
    ]),
    0x60F4: ("Following error actual value", VAR, var("", INT32, "ro", "0", True)),
    0x60FF: ("Target velocity", VAR, var("", INT32, "rww", "0", True)),
    0x6502: ("Supported drive modes", VAR, var("", UINT32, "ro", "0x000001E4")),  # bits 2, 5-8: PV, homing, IP, CSP, CSV
})


def _var_lines(section: str, name: str, sub: Sub, object_type: int = VAR) -> list[str]:
    _, dtype, access, default, pdo = sub
    return [f"[{section}]", f"ParameterName={name}", f"ObjectType=0x{object_type:X}", f"DataType=0x{dtype:04X}",
            f"AccessType={access}", f"DefaultValue={default}", f"PDOMapping={int(pdo)}", ""]


def object_lines(index: int) -> list[str]:
    name, otype, body = OBJECTS[index]
    if otype == VAR:
        return _var_lines(f"{index:04X}", name, body)  # type: ignore[arg-type]
    subs: list[Sub | None] = body  # type: ignore[assignment]
    present = [(i + 1, s) for i, s in enumerate(subs) if s is not None]
    count_access = "rw" if index in (0x1003, 0x1600, 0x1601, 0x1602, 0x1603, 0x1A00, 0x1A01, 0x1A02, 0x1A03) else "ro"
    count_default = "0" if index == 0x1003 else str(len(subs))
    if 0x1600 <= index <= 0x1603 or 0x1A00 <= index <= 0x1A03:
        count_default = str(sum(1 for s in subs if s and s[3] != "0"))
    lines = [f"[{index:04X}]", f"ParameterName={name}", f"ObjectType=0x{otype:X}", f"SubNumber={len(present) + 1}", ""]
    lines += _var_lines(f"{index:04X}sub0", "Number of entries", var("", UINT8, count_access, count_default))
    for sub_index, sub in present:
        lines += _var_lines(f"{index:04X}sub{sub_index:X}", sub[0], sub)
    return lines


def eds_text() -> str:
    mandatory = [0x1000, 0x1001, 0x1018]
    manufacturer: list[int] = []
    optional = sorted(i for i in OBJECTS if i not in mandatory and i not in manufacturer)
    head = [
        "; Generated by eds/generate.py - edit the generator, not this file.",
        "[FileInfo]", "FileName=nurbsmotion-servo.eds", "FileVersion=1", "FileRevision=0", "EDSVersion=4.0",
        "Description=Generic CiA-402 servo drive (PV 3, homing 6, IP 7, CSP 8, CSV 9) simulated by nurbsmotion",
        "CreationTime=12:00PM", "CreationDate=11-22-2026", "CreatedBy=nurbsmotion",
        "ModificationTime=12:00PM", "ModificationDate=11-22-2026", "ModifiedBy=nurbsmotion", "",
        "[DeviceInfo]", "VendorName=nurbsmotion", "VendorNumber=0x00000000", "ProductName=nurbsmotion servo",
        "ProductNumber=0x4E4D0402", "RevisionNumber=0x00010000", "OrderCode=NM-SERVO",
        *[f"BaudRate_{b}={int(b in (125, 250, 500, 1000))}" for b in (10, 20, 50, 125, 250, 500, 800, 1000)],
        "SimpleBootUpMaster=0", "SimpleBootUpSlave=1", "Granularity=8", "DynamicChannelsSupported=0",
        "GroupMessaging=0", "NrOfRXPDO=4", "NrOfTXPDO=4", "LSS_Supported=0", "",
        "[DummyUsage]", *[f"Dummy000{i}=0" for i in range(1, 8)], "",
        "[Comments]", "Lines=0", "",
    ]
    lines = list(head)
    for title, group in (("MandatoryObjects", mandatory), ("OptionalObjects", optional), ("ManufacturerObjects", manufacturer)):
        lines += [f"[{title}]", f"SupportedObjects={len(group)}"]
        lines += [f"{n}=0x{index:04X}" for n, index in enumerate(group, 1)] + [""]
        for index in group:
            lines += object_lines(index)
    return "\n".join(lines)


if __name__ == "__main__":
    out = Path(__file__).with_name("nurbsmotion-servo.eds")
    out.write_text(eds_text(), encoding="ascii")
    print(f"wrote {out}")
