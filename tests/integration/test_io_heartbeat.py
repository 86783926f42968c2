"""The I/O node's heartbeat through the daemon in this process (simulated drives and CiA-401
node on a private virtual bus): silencing the node aborts the job and disables the drives with
one line naming the node, nothing starts while it is lost, and reset brings it back."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from nurbsmotion.cli.status import format_status
from nurbsmotion.errors import InputError
from nurbsmotion.service.daemon import Daemon
from tests.integration.daemon_helpers import daemon_in_process
from tests.helpers import wait_for

IO = """\
io:
  node_id: 10
  inputs: {estop: {bit: 0, active_low: true}, limit_x_max: 1}
  outputs: {coolant_flood: 0}
"""


@pytest.fixture
def machine(tmp_path: Path) -> Iterator[Daemon]:
    with daemon_in_process(tmp_path / "data", IO, "hb") as daemon:
        yield daemon


def wait_job(daemon: Daemon, job_id: str, timeout_s: float = 30.0) -> dict:
    return wait_for(lambda: (info := daemon.controller.job_info(job_id)["job"]).get("outcome") and info["outcome"],
                      timeout_s, f"job {job_id} end")


def test_a_silent_io_node_aborts_motion_and_reset_brings_it_back(machine):
    controller, sim = machine.controller, machine.simulation.network
    node = sim.io_nodes[10]
    assert node.node.sdo[0x1016][1].raw == 127 << 16 | 500  # it watches the master's heartbeat too
    job = controller.submit("p.nc", "G21 G90\nM8\nG01 X50 F600\n")["job"]["id"]
    wait_for(lambda: controller.status()["job"]["cycle"] > 20, 10.0, "moving")
    node.detach()  # the node goes silent (power loss, cable)
    outcome = wait_job(machine, job)
    assert outcome["outcome"] == "fault"
    assert outcome["reason"].startswith("io node 10: no heartbeat for ")
    assert outcome["reason"].endswith(" ms (consumer time 300 ms): its inputs are unknown: quick stop, then every "
                                      "drive disabled")
    wait_for(lambda: controller.status()["phase"] == "disabled", 5.0, "axes disabled")
    status = controller.status()
    assert status["io"]["lost"].startswith("no heartbeat for ") and status["io"]["estop_active"] is True
    assert any(line.startswith("io node 10: inputs active none (unknown), outputs on none, LOST: no heartbeat")
               for line in format_status(status))
    with pytest.raises(InputError, match=r"^submit: io node 10 lost \(no heartbeat for \d+ ms \(consumer time 300 ms\)\)"
                                         r": its inputs are unknown; reset brings it up again$"):
        controller.submit("again.nc", "G21 G90\nG01 X1 F600\n")
    with pytest.raises(InputError, match=r"^reset: node 10: bring-up step 'I/O device type': no SDO answer"):
        controller.reset()  # still silent: it cannot be brought up

    node.attach(sim.network)  # back (boot-up, defaults)
    controller.reset()
    assert controller.status()["io"]["lost"] is None
    assert controller.status()["io"]["inputs"] == {"estop": False, "limit_x_max": False}
    job = controller.submit("again.nc", "G21 G90\nG01 X1 F600\n")["job"]["id"]
    assert wait_job(machine, job)["outcome"] == "completed"
    sim.set_io_input("estop", True)  # its inputs arrive again
    wait_for(lambda: controller.status()["io"]["estop_active"], 5.0, "e-stop seen")
