"""DATA_DIR/offsets.json: written atomically, read back exactly, a corrupt file named by field."""

import json

import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.program import CoordinateState
from nurbsmotion.service.machine_state import (MachineState, cleared, load_state, save_state, selected, state_path,
                                               with_offset)


def test_no_file_is_the_zero_state(tmp_path):
    assert load_state(tmp_path / "data") == MachineState()


def test_a_saved_state_reads_back_equal_and_no_temporary_file_remains(tmp_path):
    state = MachineState(CoordinateState().with_work_offset(2, (10.0, -5.0, 0.25)), 3)
    state = selected(state, "g55")
    save_state(tmp_path, state)
    assert load_state(tmp_path) == state
    assert [p.name for p in tmp_path.iterdir()] == ["offsets.json"]
    assert json.loads(state_path(tmp_path).read_text())["coordinates"]["active"] == "G55"


@pytest.mark.parametrize("content, where", [
    ('{"format": 1, "coordinates": {"work_offsets_mm": {"G55": [1, 2]}}}', "offsets.json: coordinates.work_offsets_mm.G55"),
    ('{"format": 1, "coordinates": {"active": "G60"}}', "offsets.json: coordinates.active"),
    ('{"format": 1, "tool_in_spindle": -1}', "offsets.json: tool_in_spindle"),
    ('{"format": 2}', "offsets.json: format"),
    ('{"format": 1,\n "coordinates": ', "offsets.json:2"),
])
def test_a_corrupt_file_is_one_error_naming_the_file_and_field(tmp_path, content, where):
    state_path(tmp_path).write_text(content)
    with pytest.raises(InputError) as err:
        load_state(tmp_path)
    assert len(str(err.value).splitlines()) == 1
    assert str(err.value).startswith(str(tmp_path / where)), str(err.value)


def test_offset_edits_keep_what_they_do_not_name():
    state = with_offset(MachineState(), "G55", (10.0, None, -2.0))
    state = with_offset(state, "G55", (None, 4.0, None))
    assert state.coordinates.work_offsets_mm[1] == (10.0, 4.0, -2.0)
    assert cleared(state, "G55").coordinates.work_offsets_mm[1] == (0.0, 0.0, 0.0)
    g92 = MachineState(CoordinateState(g92_mm=(1.0, 2.0, 3.0), g92_applied=True, g28_mm=(5.0, 5.0, 5.0)))
    assert cleared(g92, "G92").coordinates.g92_applied is False and cleared(g92, "G92").coordinates.g92_mm == (0, 0, 0)
    assert cleared(g92, "g28").coordinates.g28_mm == (0.0, 0.0, 0.0)
    with pytest.raises(InputError, match="field 'clear': must be one of G54 .* G92 G28 G30, got 'G99'"):
        cleared(g92, "G99")
    with pytest.raises(InputError, match="field 'system': must be one of G54"):
        with_offset(state, "G53", (1.0, None, None))
