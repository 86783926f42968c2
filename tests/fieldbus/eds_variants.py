"""Variants of the packaged EDS for bring-up tests: objects removed, limits or access changed,
mapping entries cut, as real vendor files differ (docs: shared reference 'real drives')."""

from __future__ import annotations

import configparser
import re
from pathlib import Path

from nurbsmotion.config import default_eds_path


def _read(path: str | Path) -> configparser.RawConfigParser:
    eds = configparser.RawConfigParser()
    eds.optionxform = str  # type: ignore[assignment,method-assign]
    eds.read(path, encoding="ascii")
    return eds


PDO_MAPPINGS = (0x1600, 0x1601, 0x1602, 0x1603, 0x1A00, 0x1A01, 0x1A02, 0x1A03)


def one_entry_pdos() -> dict[str, object]:
    """eds_variant arguments for a drive whose PDOs map one entry each (Technosoft IDM)."""
    return {"drop_subs": {m: tuple(range(2, 9)) for m in PDO_MAPPINGS},
            "set_keys": {f"{m:04X}": {"SubNumber": "2"} for m in PDO_MAPPINGS}}


def eds_variant(folder: Path, name: str, *, drop: tuple[int, ...] = (), drop_subs: dict[int, tuple[int, ...]] | None = None,
                set_keys: dict[str, dict[str, str]] | None = None) -> Path:
    """Write ``folder/name``: the packaged EDS without the objects ``drop`` (and sub-entries
    ``drop_subs``; a default entry count is cut to the entries left), with ``set_keys``
    {section: {key: value}} applied."""
    eds = _read(default_eds_path())
    for index, subs in (drop_subs or {}).items():
        count = f"{index:04X}sub0"
        if eds.has_section(count):
            left = sum(1 for n in range(1, 9) if n not in subs and eds.has_section(f"{index:04X}sub{n:X}"))
            default = int(eds.get(count, "DefaultValue"), 0)
            eds.set(count, "DefaultValue", str(min(default, left)))
    for section in list(eds.sections()):
        match = re.match(r"^([0-9A-F]{4})(?:sub([0-9A-F]+))?$", section)
        if not match:
            continue
        index, sub = int(match.group(1), 16), match.group(2)
        if index in drop or (sub is not None and int(sub, 16) in (drop_subs or {}).get(index, ())):
            eds.remove_section(section)
    for section, keys in (set_keys or {}).items():
        for key, value in keys.items():
            eds.set(section, key, value)
    path = folder / name
    with path.open("w", encoding="ascii") as out:
        eds.write(out, space_around_delimiters=False)
    return path
