"""config/can0.example.yaml, the three-axis mill of docs/commissioning.md, passes the
project's configuration validation, the offline drives check and the homing plan check of
every axis against the vendor EDS files it names."""

from __future__ import annotations

from pathlib import Path

from nurbsmotion.cli import main
from nurbsmotion.config import load_config
from nurbsmotion.fieldbus.homing_check import plan_homing

EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "can0.example.yaml"


def test_it_loads_as_a_mill_with_a_spindle_and_an_io_node():
    config = load_config(EXAMPLE)
    assert (config.bus.interface, config.bus.channel) == ("socketcan", "can0")
    assert [(a.name, a.node_id, a.mode) for a in config.axes] == [("X", 1, "csp"), ("Y", 2, "csp"), ("Z", 3, "csp")]
    assert all(a.identity is not None and a.homing is not None and a.soft_limits_mm for a in config.axes)
    assert config.spindle.node_id == 4 and config.spindle.mode.value == "csv"
    assert config.io is not None and config.io.node_id == 10
    assert {s.name for s in config.io.inputs} >= {"estop", "limit_x_min", "limit_z_max"}
    assert not config.simulate


def test_the_drives_check_passes_offline(capsys):
    assert main(["drives", "check", "--config", str(EXAMPLE)]) == 0
    assert capsys.readouterr().out.count("cyclic synchronous position (mode 8): OK") == 3


def test_every_axis_homing_fits_its_drive():
    """plan_homing (fieldbus.homing_check) raises the one-line refusal where an EDS cannot home."""
    config = load_config(EXAMPLE)
    for i, axis in enumerate(config.axes):
        assert axis.homing is not None and axis.homing.on_drive
        assert plan_homing(config, i) is not None
