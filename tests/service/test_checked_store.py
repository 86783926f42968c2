"""The checked-program store: an entry loads only under its own key, format and version;
anything else (another key, a corrupt file, an older format) is read and checked again."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from nurbsmotion.program import ReadOptions
from nurbsmotion.program.gcode import parse_gcode
from nurbsmotion.service import checked_store
from nurbsmotion.service.checked_store import CheckedStore, check_key, load_checked, save_checked, text_digest

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
