"""Jog off an active limit switch (LinuxCNC's and grblHAL's way), through the control API of
the daemon in this process, with simulated drives and a simulated CiA-401 node on a private
virtual bus: a jog runs onto the switch (the simulated input becomes active), the job faults,
only a jog of that axis away from the switch may start, and the switch trips again once it
has cleared."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from nurbsmotion.service.client import Client
from nurbsmotion.service.daemon import Daemon
from tests.integration.daemon_helpers import daemon_in_process
from tests.helpers import wait_for

IO = """\
io:
  node_id: 10
  inputs: {limit_x_max: 1, limit_y: {bit: 2, active_low: true}, z_bottom: {bit: 3, limit: Z-}}
"""
X_MAX = "limit input limit_x_max (io node 10 bit 1) is active: axis X is on its limit switch"


@pytest.fixture
def machine(tmp_path: Path) -> Iterator[tuple[Daemon, Client]]:
    with daemon_in_process(tmp_path / "data", IO, "lj") as daemon, Client(daemon.config.control.socket) as client:
        yield daemon, client


def press(daemon: Daemon, name: str, active: bool) -> None:
    daemon.simulation.network.set_io_input(name, active)  # type: ignore[union-attr]
    wait_for(lambda: daemon.controller.status()["io"]["inputs"][name] is active, 5.0, f"{name} {active}")


def wait_job(client: Client, job_id: str, timeout_s: float = 30.0) -> dict:
    return wait_for(lambda: (job := client.call("job", id=job_id)["job"])["outcome"] is not None and job["outcome"],
                      timeout_s, f"the end of job {job_id}", poll_s=0.05)


def x_mm(client: Client, axis: int = 0) -> float:
    return client.call("status")["axes"][axis]["commanded_mm"]


def run_onto(daemon: Daemon, client: Client, axis: str, direction: str, switch: str) -> dict:
    """A continuous jog of ``axis`` that meets ``switch`` after a few cycles: the job's outcome."""
    job = client.call("jog", axis=axis, direction=direction, speed=20.0)["job"]["id"]
    wait_for(lambda: client.call("status")["job"]["cycle"] > 50, 10.0, "moving")
    client.call("jog_renew")
    press(daemon, switch, True)
    outcome = wait_job(client, job)
    client.call("reset")
    return outcome


def test_a_jog_off_the_switch_is_the_only_motion_while_it_is_active_and_it_trips_again_once_cleared(machine):
    daemon, client = machine
    outcome = run_onto(daemon, client, "X", "+", "limit_x_max")
    assert outcome["outcome"] == "fault"
    assert outcome["reason"] == "limit input limit_x_max (io node 10 bit 1) is active: axis X"
    on_switch = x_mm(client)
    assert on_switch > 0.5

    refused = {  # towards the switch, another axis, a job, MDI: one line naming the input
        ("jog", "X+1"): client.request("jog", axis="X", distance=1.0)["error"],
        ("jog", "X+"): client.request("jog", axis="X", direction="+", speed=5.0)["error"],
        ("jog", "Y-1"): client.request("jog", axis="Y", distance=-1.0)["error"],
        ("mdi", ""): client.request("mdi", text="G91 G01 X-1 F600")["error"],
        ("submit", ""): client.request("submit", name="p.nc", program="G21 G90\nG01 X0 F600\n")["error"],
    }
    assert refused == {
        ("jog", "X+1"): f"jog: {X_MAX}: jog X+ moves towards it; jog X- moves away",
        ("jog", "X+"): f"jog: {X_MAX}: jog X+ moves towards it; jog X- moves away",
        ("jog", "Y-1"): f"jog: {X_MAX}: only a jog X- (away from it) may move",
        ("mdi", ""): f"mdi: {X_MAX}: only a jog X- (away from it) may move",
        ("submit", ""): f"submit: {X_MAX}: only a jog X- (away from it) may move",
    }
    assert x_mm(client) == on_switch  # nothing moved

    job = client.call("jog", axis="X", distance=-0.5)["job"]["id"]  # incremental, away: allowed
    assert wait_job(client, job)["outcome"] == "completed"
    assert x_mm(client) == pytest.approx(on_switch - 0.5, abs=1e-6)

    job = client.call("jog", axis="X", direction="-", speed=5.0)["job"]["id"]  # continuous, away: allowed
    wait_for(lambda: x_mm(client) < on_switch - 0.8, 5.0, "moving off", poll_s=0.01)
    client.call("jog_renew")
    press(daemon, "limit_x_max", False)  # off the switch: armed again
    client.call("jog_stop")
    assert wait_job(client, job)["outcome"] == "stopped"

    job = client.call("jog", axis="X", distance=1.0)["job"]["id"]  # towards it again: allowed, and it trips
    wait_for(lambda: client.call("status")["job"] and client.call("status")["job"]["cycle"] > 10, 5.0, "moving")
    press(daemon, "limit_x_max", True)
    outcome = wait_job(client, job)
    assert outcome["outcome"] == "fault" and outcome["reason"].startswith("limit input limit_x_max")


def test_a_switch_whose_end_is_not_said_is_left_the_way_the_axis_came(machine):
    daemon, client = machine
    outcome = run_onto(daemon, client, "Y", "-", "limit_y")
    assert outcome["reason"] == "limit input limit_y (io node 10 bit 2, active low) is active: axis Y"
    assert client.request("jog", axis="Y", distance=-1.0)["error"].endswith(": jog Y- moves towards it; "
                                                                            "jog Y+ moves away")
    job = client.call("jog", axis="Y", distance=1.0)["job"]["id"]
    assert wait_job(client, job)["outcome"] == "completed"
    press(daemon, "limit_y", False)
    job = client.call("jog", axis="Y", distance=-1.0)["job"]["id"]
    assert wait_job(client, job)["outcome"] == "completed"


def test_a_switch_found_active_at_rest_with_no_end_said_is_refused_and_limit_axis_minus_names_the_end(machine):
    daemon, client = machine
    press(daemon, "limit_y", True)  # no motion: which end is not known
    assert client.request("jog", axis="Y", distance=1.0)["error"] == (
        "jog: limit input limit_y (io node 10 bit 2, active low) is active: axis Y is on its limit switch, and which "
        "end it is is not known (name the input limit_y_min / _max or give limit: Y- / Y+): move the axis off it by hand")
    press(daemon, "limit_y", False)
    press(daemon, "z_bottom", True)  # limit: Z-
    assert client.request("jog", axis="Z", distance=-1.0)["error"].endswith(": jog Z- moves towards it; "
                                                                            "jog Z+ moves away")
    job = client.call("jog", axis="Z", direction="+", speed=5.0)["job"]["id"]
    wait_for(lambda: x_mm(client, 2) > 0.05, 5.0, "Z moving up")
    client.call("jog_stop")
    assert wait_job(client, job)["outcome"] == "stopped"
