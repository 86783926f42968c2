"""io: one CiA-401 node with named inputs and outputs by bit; errors name the YAML line."""

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.config.io import IoConfig, IoSignal

AXES = "axes: [{name: X, node_id: 1}]\n"


def _errors(text: str) -> list[str]:
    with pytest.raises(InputError) as info:
        parse_config(text, "m.yaml")
    return str(info.value).splitlines()


def test_signals_by_bit_and_with_polarity():
    cfg = parse_config(AXES + "io:\n  node_id: 10\n  inputs:\n    estop: {bit: 0, active_low: true}\n"
                       "    limit_x_min: 9\n  outputs: {coolant_flood: 0, coolant_mist: 1}\n")
    assert cfg.io == IoConfig(10, inputs=(IoSignal("estop", 0, True), IoSignal("limit_x_min", 9)),
                              outputs=(IoSignal("coolant_flood", 0), IoSignal("coolant_mist", 1)))
    assert cfg.io.input_groups == 2 and cfg.io.output_groups == 1


def test_no_io_section_means_none_and_empty_lists_are_allowed():
    assert parse_config(AXES).io is None
    io = parse_config(AXES + "io: {node_id: 5, inputs: {}}\n").io
    assert io.inputs == () and io.outputs == () and io.input_groups == 0


def test_bit_used_twice_and_bad_names_are_located():
    text = AXES + ("io:\n  node_id: 10\n  inputs:\n    estop: 0\n    probe: 0\n    2bad: 1\n"
                   "    limit: 64\n    door: {active_low: true}\n")
    assert _errors(text) == [
        "m.yaml:6: io.inputs.probe: bit 0 is already used by 'estop'",
        "m.yaml:7: io.inputs.2bad: signal name '2bad' must be an identifier (letters, digits, _)",
        "m.yaml:8: io.inputs.limit: must be <= 63, got 64",
        "m.yaml:9: io.inputs.door: missing required key 'bit'",
    ]


def test_node_id_shared_with_an_axis_is_refused():
    assert _errors(AXES + "io:\n  node_id: 1\n") == ["m.yaml:3: io.node_id: node id 1 is already used by an axis"]


def test_node_id_is_required_and_inputs_must_be_a_mapping():
    assert _errors(AXES + "io:\n  inputs: [estop]\n") == [
        "m.yaml:3: io: missing required key 'node_id'",
        "m.yaml:3: io.inputs: must be a mapping of name: bit",
    ]


def test_an_input_may_name_the_axis_it_limits():
    from nurbsmotion.service.machine_io import LimitSwitch, limit_inputs, limit_switches

    axes = "axes: [{name: X, node_id: 1}, {name: Y, node_id: 2}]\n"
    cfg = parse_config(axes + "io:\n  node_id: 10\n  inputs:\n    x_neg: {bit: 2, active_low: true, limit: X}\n"
                              "    limit_y_max: 3\n    probe: 4\n    y_low: {bit: 5, limit: Y-}\n    limit_x: 6\n")
    assert cfg.io.inputs[0] == IoSignal("x_neg", 2, True, limit="X")
    assert limit_inputs(cfg) == {"x_neg": "X", "limit_y_max": "Y", "y_low": "Y", "limit_x": "X"}
    assert limit_switches(cfg) == {"x_neg": LimitSwitch("x_neg", "X", 0), "limit_y_max": LimitSwitch("limit_y_max", "Y", 1),
                                   "y_low": LimitSwitch("y_low", "Y", -1), "limit_x": LimitSwitch("limit_x", "X", 0)}
    assert _errors(axes + "io:\n  node_id: 10\n  inputs:\n    x_neg: {bit: 2, limit: A}\n"
                          "  outputs:\n    lamp: {bit: 0, limit: X}\n") == [
        "m.yaml:5: io.inputs.x_neg.limit: no axis 'A' (axes: X, Y; X- / X+ name its negative / positive end)",
        "m.yaml:7: io.outputs.lamp.limit: an output is no limit switch: limit is for inputs"]
