"""The I/O node of a machine's ``io`` section in ``SimNetwork.for_machine`` / ``nurbsmotion
sim``, pressed by name from a test and read by the master's own ``IoNode``."""

from __future__ import annotations

import uuid
from pathlib import Path

import canopen
import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.io import IoNode
from nurbsmotion.sim import SimNetwork
from nurbsmotion.sim.homing import HomeSensors

from conftest import wait_for


def _machine(tmp_path: Path, channel: str, io: bool = True):
    path = tmp_path / "machine.yaml"
    text = (f"bus: {{interface: virtual, channel: {channel}}}\n"
            "axes:\n  - {name: X, node_id: 1}\n")
    if io:
        text += ("io:\n  node_id: 10\n  inputs:\n    estop: {bit: 0, active_low: true}\n    limit_x_min: 9\n"
                 "  outputs:\n    coolant_flood: 0\n")
    path.write_text(text)
    return load_config(path)


def test_the_io_section_starts_a_node_whose_inputs_a_test_presses_by_name(tmp_path: Path) -> None:
    channel = f"sim-io-{uuid.uuid4().hex}"
    machine = _machine(tmp_path, channel)
    with SimNetwork.for_machine(machine) as net:
        node = net.io_nodes[10]
        assert (node.input_groups, node.output_groups) == (2, 1)
        assert node.input(0) and not node.input(9)  # e-stop wire closed (active low): released
        master = canopen.Network()
        master.connect(interface="virtual", channel=channel)
        io = IoNode(master, machine.io)
        try:
            io.bring_up(heartbeat_producer_ms=50)
            assert io.inputs == {"estop": False, "limit_x_min": False}
            wait_for(lambda: node.nmt_state == 0x05, what="NMT start reached the node")
            net.set_io_input("estop", True)
            wait_for(lambda: io.input("estop") is True, what="estop pressed via TPDO1")
            assert not node.input(0)  # the wire opened
            net.set_io_input("limit_x_min", True)
            wait_for(lambda: io.input("limit_x_min") is True, what="limit via TPDO1")
            io.set_outputs({"coolant_flood": True})
            wait_for(lambda: node.output(0), what="coolant output via RPDO1")
        finally:
            io.close()
            master.disconnect()


def test_an_unknown_input_name_is_one_clear_error(tmp_path: Path) -> None:
    net = SimNetwork.for_machine(_machine(tmp_path, f"sim-io-{uuid.uuid4().hex}"))
    with pytest.raises(InputError, match=r"input 'estp'.*have \['estop', 'limit_x_min'\]"):
        net.set_io_input("estp", True)


def test_without_an_io_section_there_is_no_io_node(tmp_path: Path) -> None:
    net = SimNetwork.for_machine(_machine(tmp_path, f"sim-io-{uuid.uuid4().hex}", io=False))
    assert net.io_nodes == {} and net.io_inputs == {}


def test_home_sensors_go_to_the_axis_drive_and_must_name_an_axis(tmp_path: Path) -> None:
    machine = _machine(tmp_path, f"sim-io-{uuid.uuid4().hex}", io=False)
    sensors = HomeSensors(negative_limit_counts=-100.0)
    net = SimNetwork.for_machine(machine, home_sensors={1: sensors})
    assert net[1].axis.home_sensors == sensors
    with pytest.raises(InputError, match="node 7 is not an axis"):
        SimNetwork.for_machine(machine, home_sensors={7: sensors})


def test_a_node_id_is_simulated_once() -> None:
    net = SimNetwork(channel=f"sim-io-{uuid.uuid4().hex}")
    net.add_drive(3)
    with pytest.raises(ValueError, match="node 3 is already simulated"):
        net.add_io_node(3)
