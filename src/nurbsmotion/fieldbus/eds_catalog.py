"""A folder of EDS/DCF files, and which one describes a node (by its 0x1018 identity).

CiA 306: the [DeviceInfo] section's VendorNumber, ProductNumber and RevisionNumber are the
values the device reports in 0x1018:01, :02 and :03. A node matches a file when vendor id and
product code are equal; among several matching files the one with the node's revision wins.
A file whose vendor and product are both 0 (or missing) identifies nothing and matches no node.
"""

from __future__ import annotations

import configparser
from dataclasses import dataclass
from pathlib import Path

from nurbsmotion.fieldbus.scan import Identity

EDS_SUFFIXES = (".eds", ".dcf")


@dataclass(frozen=True)
class EdsEntry:
    path: Path
    vendor_id: int | None
    product_code: int | None
    revision: int | None
    vendor_name: str
    product_name: str

    @property
    def identifies(self) -> bool:
        return bool(self.vendor_id or self.product_code)


@dataclass(frozen=True)
class EdsMatch:
    """The file chosen for a node (None: no file matches), the other candidates, and a note
    (revision differs, several files match)."""

    entry: EdsEntry | None
    others: tuple[EdsEntry, ...] = ()
    note: str = ""


def cia306_int(text: str) -> int:
    """An EDS integer (CiA 306 4.4: decimal, ``0x`` hexadecimal or leading-``0`` octal)."""
    value = text.strip()
    if value.lower().startswith("0x"):
        return int(value, 16)
    if len(value) > 1 and value.startswith("0"):
        return int(value, 8)
    return int(value, 10)


def read_entry(path: Path) -> EdsEntry:
    """The [DeviceInfo] identity of one file; ValueError (one line) for an unreadable file."""
    parser = configparser.RawConfigParser(strict=False, inline_comment_prefixes=(";",))
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    try:
        parser.read_string(path.read_text(encoding="latin-1"), source=str(path))
    except OSError as err:
        raise ValueError(f"{path}: cannot read: {err.strerror or err}") from None
    except configparser.Error as err:
        line = getattr(err, "lineno", None)
        first = str(err).splitlines()[0][:160]
        raise ValueError(f"{path}{f':{line}' if line else ''}: not a readable EDS/DCF: {first}") from None
    if not parser.has_section("DeviceInfo"):
        raise ValueError(f"{path}: has no [DeviceInfo] section")

    def number(key: str) -> int | None:
        text = parser.get("DeviceInfo", key, fallback="").strip()
        if not text:
            return None
        try:
            return cia306_int(text)
        except ValueError:
            raise ValueError(f"{path}: [DeviceInfo] {key}={text!r} is not a number") from None

    return EdsEntry(path, number("VendorNumber"), number("ProductNumber"), number("RevisionNumber"),
                    parser.get("DeviceInfo", "VendorName", fallback="").strip(),
                    parser.get("DeviceInfo", "ProductName", fallback="").strip())


def read_catalog(folder: Path) -> tuple[list[EdsEntry], list[str]]:
    """Every *.eds / *.dcf directly in ``folder`` (sorted by name), and one line per file that
    could not be read or identifies nothing (nothing is skipped silently)."""
    entries: list[EdsEntry] = []
    problems: list[str] = []
    for path in sorted(p for p in folder.iterdir() if p.suffix.lower() in EDS_SUFFIXES and p.is_file()):
        try:
            entry = read_entry(path)
        except ValueError as err:
            problems.append(str(err))
            continue
        if not entry.identifies:
            problems.append(f"{path}: [DeviceInfo] gives no VendorNumber/ProductNumber: it matches no node")
        entries.append(entry)
    return entries, problems


def match(identity: Identity | None, catalog: list[EdsEntry]) -> EdsMatch:
    """The file for a node reporting ``identity`` (see the module docstring)."""
    if identity is None or identity.product_code is None:
        return EdsMatch(None, note="the node's identity (0x1018:01/02) is unknown")
    same = [e for e in catalog if e.identifies and (e.vendor_id, e.product_code) == (identity.vendor_id,
                                                                                      identity.product_code)]
    if not same:
        return EdsMatch(None, note=f"no file has vendor 0x{identity.vendor_id:08X} product "
                                   f"0x{identity.product_code:08X}")
    exact = [e for e in same if identity.revision is not None and e.revision == identity.revision]
    chosen = (exact or same)[0]
    others = tuple(e for e in same if e is not chosen)
    notes = []
    if not exact and identity.revision is not None and chosen.revision is not None:
        notes.append(f"revision differs: node 0x{identity.revision:08X}, file 0x{chosen.revision:08X}")
    if others:
        notes.append(f"{len(others)} more file(s) match: {', '.join(e.path.name for e in others)}")
    return EdsMatch(chosen, others, "; ".join(notes))


def vendor_names(catalog: list[EdsEntry]) -> dict[int, str]:
    """Vendor id -> VendorName of the files (adds to scan.VENDOR_NAMES for this folder)."""
    return {e.vendor_id: e.vendor_name for e in catalog if e.vendor_id and e.vendor_name}
