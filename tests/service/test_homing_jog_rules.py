"""The pure rules of homing and jog in the service: order, when homing is required, the
jog's target and refusals, its G-code line; the CLI's jog words."""

from __future__ import annotations

import dataclasses

import pytest

from nurbsmotion.cli.jog import jog_fields
from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.service.homing import homing_order, homing_required
from nurbsmotion.service.jog import JogRequest, jog_gcode, jog_request, jog_target_mm

AXES = """axes:
  - {name: X, node_id: 1, soft_limits_mm: [-10, 50], max_velocity_mm_s: 100, homing: {method: here, order: 3}}
  - {name: Y, node_id: 2, homing: {method: 37, order: 1}}
  - {name: Z, node_id: 3}
"""


def config(extra: str = "", bus: str = "virtual"):
    return parse_config(f"bus: {{interface: {bus}, channel: c}}\n{extra}{AXES}", "m.yaml")


def test_homing_order_and_which_axes():
    cfg = config()
    assert homing_order(cfg) == [1, 0]  # Y (order 1), X (order 3); Z has no homing:
    assert homing_order(cfg, ["x", "Y"]) == [1, 0]  # named axes still go in the configured order
    with pytest.raises(InputError, match=r"field 'axes': axis Z has no homing: section in m.yaml \(axes\[2\].homing\)"):
        homing_order(cfg, ["Z"])
    unordered = dataclasses.replace(cfg, axes=tuple(dataclasses.replace(a, homing=dataclasses.replace(a.homing, order=None))
                                                  if a.homing else a for a in cfg.axes))
    assert homing_order(unordered) == [0, 1]  # the axes list order


def test_homing_is_required_on_real_buses_unless_set():
    assert not homing_required(config())
    assert homing_required(config(bus="socketcan"))
    assert not homing_required(config("simulate: true\n", bus="socketcan"))
    assert homing_required(config("require_homing: true\n"))
    assert not homing_required(config("require_homing: false\n", bus="socketcan"))
    with pytest.raises(InputError, match="m.yaml:2: require_homing: must be"):
        config("require_homing: 1\n")


def test_jog_targets_and_refusals():
    x = config().axes[0]
    assert jog_target_mm(JogRequest("X", distance_mm=10.0), x, 5.0) == 15.0
    assert jog_target_mm(JogRequest("X", position_mm=-10.0), x, 5.0) == -10.0
    assert jog_target_mm(JogRequest("X", direction=-1, speed_mm_s=20), x, 5.0) == -10.0
    cases = [(JogRequest("X", distance_mm=50.0), "jog X+50: axis X would reach 55 mm, beyond the soft limit 50 mm"),
             (JogRequest("X", position_mm=5.0), "jog X 5: axis X is at 5 mm already: nothing to move"),
             (JogRequest("X", direction=1, speed_mm_s=150), "jog X+: speed 150 mm/s is above axis X's "
                                                            "max_velocity_mm_s 100")]
    for request, message in cases:
        with pytest.raises(InputError) as err:
            jog_target_mm(request, x, 5.0)
        assert str(err.value) == message
    with pytest.raises(InputError, match="jog Z-: axis Z has no soft_limits_mm: a continuous jog needs an end"):
        jog_target_mm(JogRequest("Z", direction=-1), config().axes[2], 0.0)
    with pytest.raises(InputError, match="jog X-: axis X is at its soft limit -10 mm already"):
        jog_target_mm(JogRequest("X", direction=-1), x, -10.0)


def test_jog_requests_and_gcode():
    assert jog_request({"axis": "x", "distance": -2.5}) == JogRequest("X", distance_mm=-2.5)
    assert jog_request({"axis": "Y", "direction": "+", "speed": 20}).direction == 1
    for fields, where in (({"axis": "X"}, "field 'distance'"), ({"axis": "X", "distance": 1, "position": 2}, "field 'distance'"),
                          ({"axis": "X", "direction": "up"}, "field 'direction'"),
                          ({"axis": "X", "distance": 1, "speed": 0}, "field 'speed'")):
        with pytest.raises(InputError) as err:
            jog_request(fields)
        assert err.value.where == where
    assert jog_gcode("X", 12.5, 20.0) == "G21 G53 G90 G01 X12.500000 F1200.000000\n"


def test_cli_jog_words():
    assert jog_fields("X+10", None, None) == {"axis": "X", "distance": 10.0}
    assert jog_fields("z-2.5", None, 5.0) == {"axis": "Z", "distance": -2.5, "speed": 5.0}
    assert jog_fields("X+", None, 20.0) == {"axis": "X", "direction": "+", "speed": 20.0}
    assert jog_fields("X", 25.0, None) == {"axis": "X", "position": 25.0}
    for word, position in (("X", None), ("X+1", 3.0), ("XY+1", None), ("X10", None)):
        with pytest.raises(ValueError):
            jog_fields(word, position, None)
