"""The checked-program store: an entry loads only under its own key, format and version;
anything else (another key, a corrupt file, an older format) is read and checked again."""

from __future__ import annotations

import hashlib
import logging
import mmap
import os
import pickle
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.program import ReadOptions
from nurbsmotion.program.curve_yaml import parse_curve_yaml
from nurbsmotion.program.gcode import parse_gcode
from nurbsmotion.program.records import BlockRecords
from nurbsmotion.service import checked_store
from nurbsmotion.service.checked_store import CheckedStore, check_key, load_checked, save_checked, text_digest
from tests.helpers import memory_of

TEXT = "G21 G90\nG01 X4 Y3 F3000\nG02 X0 Y0 I-2 J-1.5\n"


def test_an_entry_loads_only_under_its_key_format_and_version(tmp_path: Path, monkeypatch):
    program = parse_gcode(TEXT, "p.nc", np.zeros(3))
    key = check_key("p.nc", text_digest(TEXT), "cfg", np.zeros(3), ReadOptions())
    path = tmp_path / "entry.checked"
    save_checked(path, key, program)
    loaded = load_checked(path, key)
    assert loaded is not None and [b.source.line for b in loaded.blocks] == [2, 3]
    assert np.allclose(loaded.blocks[1].end, program.blocks[1].end)
    assert load_checked(path, "another key") is None
    monkeypatch.setattr(checked_store, "FORMAT_VERSION", checked_store.FORMAT_VERSION + 1)
    assert load_checked(path, key) is None  # an entry of an older format: read again
    monkeypatch.undo()
    path.write_bytes(path.read_bytes()[:-20])  # cut short: a corrupt pickle
    assert load_checked(path, key) is None
    assert load_checked(tmp_path / "none.checked", key) is None


def test_the_key_changes_with_everything_the_check_depends_on():
    base = dict(name="p.nc", text_sha256=text_digest(TEXT), config_sha256="cfg", start_xyz=np.zeros(3),
                options=ReadOptions())
    key = check_key(**base)  # type: ignore[arg-type]
    assert key == check_key(**base)  # type: ignore[arg-type]
    for change in ({"name": "q.nc"}, {"text_sha256": text_digest(TEXT + "M30\n")}, {"config_sha256": "other"},
                   {"start_xyz": np.array([0.0, 0.0, 0.001])}, {"options": ReadOptions(block_delete=False)},
                   {"options": ReadOptions(start_line=2)}):
        assert check_key(**{**base, **change}) != key, change  # type: ignore[arg-type]


def test_prune_keeps_the_newest_entries(tmp_path: Path):
    store = CheckedStore(tmp_path, "cfg")
    program = parse_gcode(TEXT, "p.nc", np.zeros(3))
    for i in range(5):
        save_checked(store.path(f"k{i}"), f"k{i}", program)
        os.utime(store.path(f"k{i}"), (1000 + i, 1000 + i))
    store.prune(keep=2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k3.checked", "k4.checked"]


def test_a_miss_prunes_the_folder_to_the_newest_entries(tmp_path: Path):
    store = CheckedStore(tmp_path, "cfg")
    for i in range(checked_store.MAX_ENTRIES + 8):
        store.path(f"k{i:02d}").write_bytes(b"x")
        os.utime(store.path(f"k{i:02d}"), (1000 + i, 1000 + i))
    store.note(True, "p.nc")
    assert len(list(tmp_path.iterdir())) == checked_store.MAX_ENTRIES + 8  # a hit writes nothing: no pruning
    store.note(False, "p.nc")
    assert sorted(p.name for p in tmp_path.iterdir())[0] == "k08.checked"
    assert len(list(tmp_path.iterdir())) == checked_store.MAX_ENTRIES
    assert (store.hits, store.misses) == (1, 1)


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
MIXED = (EXAMPLES / "mixed.nc").read_text()  # lines, arcs, a NURBS block (G6.2)


def round_trip(tmp_path: Path, program, key: str = "k"):
    path = tmp_path / f"{key}.checked"
    save_checked(path, key, program)
    loaded = load_checked(path, key)
    assert loaded is not None
    return loaded


@pytest.mark.parametrize("program", [
    pytest.param(lambda: parse_gcode(MIXED, "mixed.nc", np.zeros(3)), id="lines-arcs-nurbs"),
    pytest.param(lambda: parse_gcode(MIXED, "mixed.nc", np.zeros(3), ReadOptions(start_line=12, safe_z_mm=5.0)),
                 id="start-line-approach"),
    pytest.param(lambda: parse_curve_yaml((EXAMPLES / "wang_table1.yaml").read_text(), "wang_table1.yaml"),
                 id="yaml-curves"),
    pytest.param(lambda: parse_gcode("G21 G90\nM3 S1000\nM5\n", "still.nc", np.zeros(3)), id="no-blocks"),
])
def test_an_entry_gives_back_the_program_it_stored(tmp_path: Path, program):
    program = program()
    loaded = round_trip(tmp_path, program)
    assert BlockRecords.of_blocks(loaded.blocks) == BlockRecords.of_blocks(program.blocks)  # every number and source
    assert [str(b.source) + b.source.text for b in loaded.blocks] == [str(b.source) + b.source.text for b in program.blocks]
    for field in ("name", "events", "coordinates", "tool_at_end", "resume", "reading"):
        assert getattr(loaded, field) == getattr(program, field), field
    assert np.array_equal(loaded.start_position, program.start_position)


def test_an_entry_is_mapped_not_read(tmp_path: Path):
    """The blocks' arrays and the text are views of the file (only the pages read are in memory)."""
    loaded = round_trip(tmp_path, parse_gcode(MIXED, "mixed.nc", np.zeros(3)))
    blocks = loaded.blocks
    assert isinstance(blocks, BlockRecords) and blocks.text is not None
    for values in (blocks.starts, blocks.lines, blocks.arcs.centres, blocks.text.data):
        assert isinstance(memory_of(values), mmap.mmap) and not values.flags.writeable
    assert pickle.loads(pickle.dumps(loaded)).blocks == blocks  # sent elsewhere: as bytes


@pytest.mark.parametrize("change", [lambda b: b[:-1], lambda b: b + b"\0", lambda b: b[:len(b) // 2],
                                    lambda b: b.replace(b"nurbsmotion-checked", b"nurbsmotion-checkeX", 1),
                                    lambda b: b[:70] + b"\xff" * 8 + b[78:]],
                         ids=["one-byte-short", "one-byte-long", "half", "header", "layout"])
def test_a_truncated_or_damaged_entry_is_refused_with_one_line(tmp_path: Path, change, caplog):
    path = tmp_path / "k.checked"
    save_checked(path, "k", parse_gcode(MIXED, "mixed.nc", np.zeros(3)))
    path.write_bytes(change(path.read_bytes()))
    caplog.set_level(logging.INFO, logger=checked_store.__name__)
    assert load_checked(path, "k") is None
    assert len(caplog.records) == 1 and "checked_entry_" in caplog.records[0].getMessage()


def test_the_text_digest_is_the_sha256_of_the_whole_text_across_chunks(monkeypatch):
    monkeypatch.setattr(checked_store, "DIGEST_CHUNK", 7)
    text = "G01 X1 (Weiß, 直线)\n" * 5
    assert text_digest(text) == hashlib.sha256(text.encode("utf-8")).hexdigest()
