"""fieldbus.eds_catalog: the [DeviceInfo] identity of EDS/DCF files and which file a node's
0x1018 identity matches, on the vendor files of tests/data/eds."""

from __future__ import annotations

from pathlib import Path

import pytest

from nurbsmotion.fieldbus.eds_catalog import cia306_int, match, read_catalog, read_entry, vendor_names
from nurbsmotion.fieldbus.scan import Identity

EDS_DIR = Path(__file__).resolve().parents[2] / "tests" / "data" / "eds"


@pytest.mark.parametrize(("text", "value"), [("0x26C", 0x26C), ("327", 327), ("017", 0o17), ("0", 0), (" 0X1a3 ", 0x1A3)])
def test_cia306_integers(text, value):
    assert cia306_int(text) == value


def test_the_vendor_files_are_read_and_files_without_an_identity_are_named():
    entries, problems = read_catalog(EDS_DIR)
    assert len(entries) == len([p for p in EDS_DIR.iterdir() if p.suffix in (".eds", ".dcf")])
    assert [p.split(":")[0] for p in problems] == [str(EDS_DIR / "pilz_prbt.eds"), str(EDS_DIR / "schunk_PRL120.eds")]
    assert vendor_names(entries)[0xFB] == "maxon motor ag"


def test_match_by_vendor_and_product_preferring_the_revision():
    entries, _ = read_catalog(EDS_DIR)
    epos4 = read_entry(EDS_DIR / "maxon_epos4_50_15_node1.dcf")
    found = match(Identity(epos4.vendor_id, epos4.product_code, epos4.revision), entries)  # type: ignore[arg-type]
    assert found.entry == epos4 and found.note == ""
    older = match(Identity(0xFB, 0x65520000, 0x01600000), entries)
    assert older.entry == epos4 and older.note == "revision differs: node 0x01600000, file 0x01700000"
    elmo = match(Identity(0x9A, 0x00030923, 0x000103F6), entries)  # two files describe the Gold drive
    assert elmo.entry is not None and elmo.entry.path.name == "elmo_Elmo.eds"
    assert elmo.note == "1 more file(s) match: elmo_Whistle_Gold_V002.dcf"
    assert match(Identity(0xFB, 0x12345678), entries).note == "no file has vendor 0x000000FB product 0x12345678"
    assert match(None, entries).entry is None
    assert match(Identity(0xFB), entries).note == "the node's identity (0x1018:01/02) is unknown"


def test_a_zero_identity_matches_nothing():
    entries, _ = read_catalog(EDS_DIR)
    assert match(Identity(0, 0), entries).entry is None  # SCHUNK's PRL120 file says 0 / 0


def test_unreadable_files_are_one_line_each(tmp_path):
    (tmp_path / "garbage.eds").write_text("this is [not\n an EDS\n")
    (tmp_path / "bad_number.eds").write_text("[DeviceInfo]\nVendorNumber=zz\nProductNumber=1\n")
    (tmp_path / "notes.txt").write_text("not an EDS, not read")
    (tmp_path / "no_info.dcf").write_text("[1000]\nParameterName=Device type\n")
    entries, problems = read_catalog(tmp_path)
    assert entries == []
    assert problems == [f"{tmp_path / 'bad_number.eds'}: [DeviceInfo] VendorNumber='zz' is not a number",
                        f"{tmp_path / 'garbage.eds'}:1: not a readable EDS/DCF: File contains no section headers.",
                        f"{tmp_path / 'no_info.dcf'}: has no [DeviceInfo] section"]
