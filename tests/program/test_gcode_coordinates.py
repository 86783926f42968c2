"""Coordinate systems in machine coordinates: G54-G59.3 set by G10 L2/L20, G92 and its
G92.1/.2/.3, G53 for one block, G28/G30 with G28.1/G30.1, initial offsets in, final out."""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.program import CoordinateState, ReadOptions, parse_gcode


def ends(text: str, start=(0.0, 0.0, 0.0), coordinates: CoordinateState | None = None):
    program = parse_gcode(text, "t.nc", start, ReadOptions(coordinates=coordinates))
    return [tuple(float(round(v, 9)) for v in b.end) for b in program.blocks]


def test_g10_l2_sets_a_work_offset_and_g55_selects_it():
    # axes not written keep their machine position, as in LinuxCNC
    assert ends("G10 L2 P2 X100 Y50 Z-20\nG1 X1 F100\nG55 G1 X1\nY1 Z0\nG54 X0 Y0") == [
        (1, 0, 0), (101, 0, 0), (101, 51, -20), (0, 0, -20)]


def test_g10_l2_p0_is_the_active_system_and_g91_does_not_make_it_incremental():
    assert ends("G56\nG91 G10 L2 P0 X10\nG10 L2 P0 X10\nG90 G0 X0") == [(10, 0, 0)]


def test_g10_l20_makes_the_current_point_have_the_given_coordinates():
    # at machine X30: G10 L20 P1 X0 -> G54 X offset 30
    program = parse_gcode("G0 X30\nG10 L20 P1 X0\nG0 X5", "t.nc")
    np.testing.assert_allclose(program.blocks[-1].end, [35, 0, 0])
    assert program.coordinates.work_offsets_mm[0] == (30.0, 0.0, 0.0)


def test_g59_1_to_g59_3_are_systems_7_to_9():
    state = CoordinateState().with_work_offset(9, (1, 2, 3))
    assert ends("G59.3 G0 X0 Y0 Z0", coordinates=state) == [(1, 2, 3)]
    program = parse_gcode("G59.1", "t.nc")
    assert program.coordinates.active_system == 7 and program.coordinates.active_name == "G59.1"


def test_g92_offsets_and_their_cancel_suspend_restore():
    text = "G0 X10\nG92 X0\nG0 X5\nG92.2\nG0 X5\nG92.3\nG0 X6\nG92.1\nG0 X1\n"
    assert ends(text) == [(10, 0, 0), (15, 0, 0), (5, 0, 0), (16, 0, 0), (1, 0, 0)]


def test_g92_adds_to_the_work_offset():
    assert ends("G10 L2 P1 X100\nG0 X0\nG92 X10\nG0 X0") == [(100, 0, 0), (90, 0, 0)]


def test_g53_moves_in_machine_coordinates_for_one_block():
    assert ends("G10 L2 P1 Z-50\nG0 Z0\nG53 G0 Z-1\nG0 Z0") == [(0, 0, -50), (0, 0, -1), (0, 0, -50)]


def test_g28_and_g30_go_through_the_given_point_to_the_stored_position():
    text = "G0 X10 Y10 Z-5\nG28.1\nG0 X0 Y0 Z0\nG28\nG0 X1\nG91 G28 Z2\nG90 G0 X0 Y0 Z0\nG30\n"
    state = CoordinateState(g30_mm=(1.0, 2.0, 3.0))
    assert ends(text, coordinates=state) == [
        (10, 10, -5), (0, 0, 0), (10, 10, -5), (1, 10, -5), (1, 10, -3), (1, 10, -5), (0, 0, 0), (1, 2, 3)]


def test_initial_offsets_come_in_and_the_final_ones_go_out():
    start = CoordinateState(active_system=2).with_work_offset(2, (5.0, 0.0, 0.0))
    program = parse_gcode("G0 X1\nG10 L2 P3 Y7\nG92 X0\nG0 X-1\nG28.1", "t.nc", options=ReadOptions(coordinates=start))
    np.testing.assert_allclose(program.blocks[0].end, [6, 0, 0])
    end = program.coordinates
    assert end.active_system == 2 and end.work_offsets_mm[2] == (0.0, 7.0, 0.0)
    assert end.g92_applied and end.g92_mm == (1.0, 0.0, 0.0) and end.g28_mm == (5.0, 0.0, 0.0)
    again = parse_gcode("G0 X0", "t.nc", options=ReadOptions(coordinates=end))  # the next job goes on from there
    np.testing.assert_allclose(again.blocks[0].end, [6, 0, 0])
    assert end.as_dict()["active"] == "G55" and end.as_dict()["work_offsets_mm"]["G56"] == [0.0, 7.0, 0.0]


def test_arcs_and_nurbs_points_are_offset_too():
    program = parse_gcode("G10 L2 P1 X100\nG0 X0 Y0\nG2 X10 Y0 I5 J0 F100\nG6.2 P2 K0 X10 Y0\nK0 X20\nK1\nK1", "t.nc")
    np.testing.assert_allclose(program.blocks[1].end, [110, 0, 0], atol=1e-9)
    np.testing.assert_allclose(program.blocks[2].end, [120, 0, 0], atol=1e-9)


def test_g90_1_makes_arc_centres_absolute_in_the_work_system():
    program = parse_gcode("G10 L2 P1 X100\nG90.1 G0 X0 Y0\nG2 X10 Y0 I5 J0 F100", "t.nc")
    assert program.blocks[1].length_mm == pytest.approx(5 * np.pi)


def test_bad_coordinate_states_are_refused():
    with pytest.raises(ValueError):
        CoordinateState(active_system=10)
    with pytest.raises(ValueError):
        CoordinateState(g28_mm=(0.0, float("nan"), 0.0))


def test_g10_rotation_and_tool_table_edits_are_refused_precisely():
    with pytest.raises(InputError, match="unsupported: coordinate system rotation"):
        parse_gcode("G10 L2 P1 R45", "t.nc")
    with pytest.raises(InputError, match=r"unsupported: G10 L10"):
        parse_gcode("G10 L10 P1 Z0", "t.nc")


def test_a_state_survives_a_round_trip_through_json():
    import json
    state = CoordinateState(active_system=8, g92_mm=(1.0, 2.0, 3.0), g92_applied=True,
                            g28_mm=(0.0, 0.0, -5.0)).with_work_offset(3, (10.0, -2.5, 0.0))
    assert CoordinateState.from_dict(json.loads(json.dumps(state.as_dict()))) == state
    assert CoordinateState.from_dict({}) == CoordinateState()


@pytest.mark.parametrize("data,where", [
    ({"active": "G60"}, "offsets.active"), ({"g92_mm": [1, 2]}, "offsets.g92_mm"),
    ({"work_offsets_mm": {"G54": [0, "x", 0]}}, "offsets.work_offsets_mm.G54"),
    ({"colour": 1}, "offsets.colour"), ({"g92_applied": 1}, "offsets.g92_applied"), ([], "offsets"),
])
def test_a_bad_persisted_state_names_its_field(data, where):
    with pytest.raises(InputError) as info:
        CoordinateState.from_dict(data)
    assert info.value.where == where
