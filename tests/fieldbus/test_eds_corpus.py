"""The real vendor EDS/DCF corpus in tests/data/eds loads with canopen and describes a CiA-402 drive.

This checks the corpus itself (each file is a usable object dictionary with the
CiA-402 controlword 0x6040 and statusword 0x6041); bring-up tests against these
files live beside the code they exercise.
"""

from pathlib import Path

import pytest
from canopen.objectdictionary import import_od

EDS_DIR = Path(__file__).resolve().parents[1] / "data" / "eds"
CORPUS = sorted(p for p in EDS_DIR.iterdir() if p.suffix.lower() in {".eds", ".dcf"})
CONTROLWORD, STATUSWORD = 0x6040, 0x6041


def test_corpus_has_files_from_at_least_eight_vendors():
    vendors = {p.name.split("_", 1)[0] for p in CORPUS}
    assert len(vendors) >= 8, sorted(vendors)


def test_every_corpus_file_is_listed_in_sources():
    sources = (EDS_DIR / "SOURCES.md").read_text(encoding="utf-8")
    assert [p.name for p in CORPUS if f"`{p.name}`" not in sources] == []


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_vendor_file_loads_as_cia402_drive(path):
    od = import_od(str(path), node_id=1)
    assert CONTROLWORD in od and STATUSWORD in od
