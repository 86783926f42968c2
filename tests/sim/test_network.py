"""SimNetwork: drives for a machine configuration, fault routing, recordings."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.sim import FaultInjection, SimNetwork
from nurbsmotion.sim.network import DriveSetupError, period_as_value_exponent


@pytest.mark.parametrize(
    "period_s,encoded",
    [(0.001, (1, -3)), (0.004, (4, -3)), (0.0005, (5, -4)), (0.00025, (25, -5)), (0.1, (1, -1)), (0.0123456, (123, -4))],
)
def test_0x60c2_encoding_of_a_period(period_s: float, encoded: tuple[int, int]) -> None:
    assert period_as_value_exponent(period_s) == encoded


def machine(channel: str, eds: str | None = None) -> SimpleNamespace:
    axis = SimpleNamespace(name="X", node_id=4, mode="ip", eds=eds, identity=SimpleNamespace(vendor_id=7, product_code=8))
    return SimpleNamespace(bus=SimpleNamespace(interface="virtual", channel=channel, bitrate=1_000_000),
                           cycle_period_s=0.004, axes=[axis])


def test_for_machine_commissions_each_drive_for_its_axis(channel: str) -> None:
    net = SimNetwork.for_machine(machine(channel), lag_cycles=3, max_velocity_counts_s=1234.0)
    drive = net[4]
    assert (net.interface, net.channel) == ("virtual", channel)
    with net:
        assert drive.axis.mode_display == 7 and drive.period_s == pytest.approx(0.004)
        assert drive.servo.lag_cycles == 3 and drive.servo.max_velocity_counts_s == 1234.0
        assert drive.value(0x1018, 1) == 7 and drive.value(0x1006) == 4000


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
