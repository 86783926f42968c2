"""The io node's limit inputs and homing (LinuxCNC's rules): a limit input that becomes
active during a homing stops it with a quick stop and one line, unless it is the homed axis'
own and its homing says ``ignore_limits`` (HOME_IGNORE_LIMITS: its limit switch is its home
switch); an active limit input refuses ``home`` on the same terms. The daemon in this
process, simulated drives with a far home switch (a long search), a simulated CiA-401 node."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from nurbsmotion.service.client import Client
from nurbsmotion.service.daemon import Daemon
from nurbsmotion.sim.homing import HomeSensors
from tests.integration.daemon_helpers import daemon_with_home_sensors
from tests.helpers import wait_for

CONFIG = """\
cycle_period_ms: 4
simulate: true
require_homing: true
bus: {{interface: virtual, channel: {channel}}}
axes:
  - {{name: X, node_id: 1, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100], max_velocity_mm_s: 200,
     max_accel_mm_s2: 2000, following_error_window_mm: 2.0,
     homing: {{method: 17, speed_search_mm_s: 10, speed_zero_mm_s: 2, accel_mm_s2: 200, ignore_limits: {ignore}}}}}
  - {{name: Y, node_id: 2, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100], max_velocity_mm_s: 200,
     max_accel_mm_s2: 2000, following_error_window_mm: 2.0, homing: {{method: here}}}}
io:
  node_id: 10
  inputs: {{limit_x_min: 1, limit_y_max: 2}}
control: {{socket: {socket}}}
data_dir: {data_dir}
"""
SENSORS = {1: HomeSensors(negative_limit_counts=-30000)}  # the drive's own switch: 3 s of search at 10 mm/s
Y_MAX = "limit input limit_y_max (io node 10 bit 2) is active: axis Y"


def machine(ignore: bool) -> Iterator[tuple[Daemon, Client]]:
    with daemon_with_home_sensors(CONFIG, "hl", SENSORS, ignore=str(ignore).lower()) as pair:
        yield pair


@pytest.fixture
def plain() -> Iterator[tuple[Daemon, Client]]:
    yield from machine(ignore=False)


@pytest.fixture
def ignoring() -> Iterator[tuple[Daemon, Client]]:
    yield from machine(ignore=True)


def press(daemon: Daemon, name: str, active: bool) -> None:
    daemon.simulation.network.set_io_input(name, active)  # type: ignore[union-attr]
    wait_for(lambda: daemon.controller.status()["io"]["inputs"][name] is active, 5.0, f"{name} {active}")


def searching(client: Client) -> None:
    """X is homing and has moved (the search is under way)."""
    assert client.call("home", axes="X")["ok"]
    wait_for(lambda: client.call("status")["axes"][0]["actual_mm"] < -1.0, 10.0, "X searching", poll_s=0.02)


def homing_end(client: Client) -> dict:
    wait_for(lambda: not client.call("status")["homing"]["busy"], 30.0, "the homing to end", poll_s=0.05)
    return client.call("status")["homing"]


def test_a_limit_input_during_a_homing_stops_it_with_a_quick_stop_and_one_line(plain):
    daemon, client = plain
    searching(client)
    press(daemon, "limit_y_max", True)
    homing = homing_end(client)
    assert homing["error"] == f"axis X: homing stopped: {Y_MAX}; the axes were quick-stopped: send reset"
    assert homing["axes"]["X"] == "not homed"
    assert client.call("status")["axes"][0]["actual_mm"] > -29.0  # stopped long before the drive's switch


def test_the_homed_axis_own_limit_input_stops_it_too_without_ignore_limits(plain):
    daemon, client = plain
    searching(client)
    press(daemon, "limit_x_min", True)
    assert homing_end(client)["error"].startswith("axis X: homing stopped: limit input limit_x_min (io node 10 bit 1)")


def test_with_ignore_limits_its_own_limit_input_neither_refuses_nor_stops_its_homing(ignoring):
    daemon, client = ignoring
    press(daemon, "limit_x_min", True)  # on the switch at the start: homing may begin
    searching(client)
    press(daemon, "limit_x_min", False)
    press(daemon, "limit_x_min", True)  # and tripping again during the search changes nothing
    homing = homing_end(client)
    assert homing["error"] is None and homing["axes"]["X"] == "homed"


def test_an_active_limit_input_of_another_axis_refuses_home_with_one_line(ignoring):
    daemon, client = ignoring
    press(daemon, "limit_y_max", True)
    assert client.request("home", axes="X")["error"] == f"home: {Y_MAX} is on its limit switch: only a jog Y- " \
                                                        f"(away from it) may move"
    assert client.call("status")["homing"]["busy"] is False
