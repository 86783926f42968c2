"""SimNetwork: drives for a machine configuration, fault routing, recordings."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.sim import FaultInjection, SimNetwork
from nurbsmotion.sim.timing import MissingSetpoint, SyncSettings
from nurbsmotion.sim.network import DriveSetupError


def machine(channel: str, eds: str | None = None) -> SimpleNamespace:
    axis = SimpleNamespace(name="X", node_id=4, mode="ip", eds=eds, identity=SimpleNamespace(vendor_id=7, product_code=8))
    return SimpleNamespace(bus=SimpleNamespace(interface="virtual", channel=channel, bitrate=1_000_000),
                           cycle_period_s=0.004, axes=[axis])


def test_for_machine_builds_each_axis_drive_out_of_the_box(channel: str) -> None:
    sync = SyncSettings(missing_setpoint=MissingSetpoint.EXTRAPOLATE, loss_periods=3)
    net = SimNetwork.for_machine(machine(channel), lag_cycles=3, max_velocity_counts_s=1234.0, sync=sync)
    drive = net[4]
    assert (net.interface, net.channel) == ("virtual", channel)
    with net:
        # nothing the master must write is pre-stored: mode and cycle are the EDS defaults
        assert drive.axis.mode_display == 8 and drive.period_s == pytest.approx(0.001)
        assert drive.value(0x1006) == 1000 and (drive.value(0x60C2, 1), drive.value(0x60C2, 2)) == (1, -3)
        assert drive.servo.lag_cycles == 3 and drive.servo.max_velocity_counts_s == 1234.0
        assert drive.value(0x1018, 1) == 7 and drive.sync_settings == sync


def test_for_machine_names_the_axis_whose_eds_does_not_load(channel: str, tmp_path: Path) -> None:
    with pytest.raises(DriveSetupError) as err:
        SimNetwork.for_machine(machine(channel, eds=str(tmp_path / "missing.eds")))
    assert err.value.axis_index == 0 and "axis X" in err.value.message


def test_inject_to_an_unknown_node_is_an_input_error(channel: str) -> None:
    net = SimNetwork(channel=channel)
    net.add_drive(1)
    with pytest.raises(InputError, match="node 5"):
        net.inject(FaultInjection("fault", node_id=5))
    with pytest.raises(ValueError):
        net.add_drive(1)


def test_write_recordings_one_file_per_drive(channel: str, tmp_path: Path) -> None:
    net = SimNetwork(channel=channel)
    for node_id in (3, 1):
        net.add_drive(node_id)
    paths = net.write_recordings(tmp_path / "rec")
    assert [p.name for p in paths] == ["node1.csv", "node3.csv"]
    paths = net.write_recordings(tmp_path / "rec", timelines=True)
    assert [p.name for p in paths] == ["node1.csv", "node1.sync.csv", "node3.csv", "node3.sync.csv"]
