"""Every real vendor EDS/DCF that bring-up accepts, homed and run end to end: the demo's
machine (its homing where the file offers it, else ``here``; its simulated switches and
index pulses) with all three axes on simulated drives built from that file, in this process;
each axis homed where the demo says, then a short program completed with exactly the
planned set-points applied (with the axis offsets the homing left)."""

from __future__ import annotations

import argparse
import contextlib
import functools
import re
import uuid
from pathlib import Path
from typing import Any, Iterator

import pytest

from nurbsmotion.cli.demo import DEMO_HOMING, demo_config, demo_sensors
from nurbsmotion.cli.run import follow
from nurbsmotion.fieldbus.homing_check import OffsetRoute
from nurbsmotion.service.client import Client
from nurbsmotion.service.daemon import Daemon
from nurbsmotion.service.link import open_link
from nurbsmotion.service.verify import drive_report
from tests.fieldbus.test_homing_check import EDS_DIR, EXPECTED
from tests.integration.daemon_helpers import home_all

ROOT = Path(__file__).resolve().parents[2]
RUNNABLE = sorted(eds for eds, (mode, _) in EXPECTED.items() if mode is not None)
PROGRAM = "G01 X5 Y5 F3000\nG01 X-5 Y2\nG01 X0 Y0\n"
# X homes on its switch edge (sampled once per 4 ms cycle at 2 mm/s: 0.008 mm) and stops
# from 2 mm/s at 200 mm/s² (v²/2a = 0.01 mm): it reads offset_mm -20 up to that much past it.
X_HOME_PAST_MM = 0.008 + 0.01 + 0.002  # + the servo model's lag of one set-point


def demo_yaml(eds: str, mode: str, channel: str, keep_homing: bool = False) -> str:
    """config/demo.yaml with every axis on ``eds`` in ``mode`` and no quick_stop_decel (in
    the simulated servo's units, outside some files' 0x6085 range); without its homing:
    sections unless ``keep_homing`` (then the demo offers what each EDS can: demo_config)."""
    text = (ROOT / "config" / "demo.yaml").read_text(encoding="utf-8")
    text = text.replace("channel: nurbsmotion-demo", f"channel: {channel}")
    text = re.sub(r"mode: (csp|ip), ", f"mode: {mode}, eds: {EDS_DIR / eds}, ", text)
    if not keep_homing:
        text = re.sub(r",\s*homing: \{[^{}]*\}", "", text)
    text = re.sub(r"quick_stop_decel: 5000000,\s*", "", text)  # an axis' key among others
    return re.sub(r",\s*quick_stop_decel: 5000000\}", "}", text)  # or its last


@contextlib.contextmanager
def demo_machine(tmp_path: Path, text: str) -> Iterator[tuple[Any, Any, Any]]:
    """(config, daemon, client): the demo's configuration of ``text`` (cli.demo.demo_config:
    its homing offered by the EDS) on simulated drives with the demo's sensors, homed."""
    path = tmp_path / "machine.yaml"
    path.write_text(text, encoding="utf-8")
    config = demo_config(argparse.Namespace(config=str(path), data_dir=str(tmp_path / "data")), tmp_path / "ctl.sock")
    daemon = Daemon(config, functools.partial(open_link, home_sensors=demo_sensors(config)))
    daemon.start()
    try:
        with Client(config.control.socket) as client:
            yield config, daemon, client
    finally:
        daemon.close()


def runs_exactly(config: Any, client: Any) -> None:
    """PROGRAM completes and the drives applied exactly its planned set-points."""
    job = client.call("submit", name="square.nc", program=PROGRAM)["job"]
    info = follow(client, job["id"], None)
    assert info["outcome"]["outcome"] == "completed", info["outcome"]
    assert drive_report(Path(info["folder"]), config).exact


@pytest.mark.slow
@pytest.mark.parametrize("eds", RUNNABLE)
def test_the_demo_machine_homes_and_runs_on_every_drive_that_can(tmp_path, eds):
    mode = EXPECTED[eds][0]
    with demo_machine(tmp_path, demo_yaml(eds, mode, f"hc-{uuid.uuid4().hex}")) as (config, _, client):
        status = home_all(client, 25.0)
        assert set(status["homing"]["axes"].values()) == {"homed"}
        at = {a["name"]: a["actual_mm"] for a in status["axes"]}
        on_drive = {a.name: a.homing.on_drive for a in config.axes}
        offered = isinstance(EXPECTED[eds][1], OffsetRoute)  # else 'here'
        assert on_drive == {"X": offered, "Y": offered, "Z": False}
        x_home = DEMO_HOMING["X"].offset_mm
        assert x_home <= at["X"] <= x_home + (X_HOME_PAST_MM if on_drive["X"] else 0.0), at
        runs_exactly(config, client)


@pytest.mark.slow
def test_an_epos4_takes_the_home_offset_in_the_vendor_object_named(tmp_path):
    """X's -20 mm written to the EPOS4's 0x30B0 ("home position", the home reads it): the
    drive reports the home at -20000 counts and the axis map stays as configured."""
    text = demo_yaml("maxon_epos4_50_15_node1.dcf", "csp", f"hc-{uuid.uuid4().hex}", keep_homing=True)
    x_homing = "offset_mm: -20, order: 2}"  # config/demo.yaml's X: method 17 to -20 mm
    assert text.count(x_homing) == 1
    text = text.replace(x_homing, "offset_mm: -20, order: 2, home_offset_object: 0x30B0, home_offset_sign: 1}")
    with demo_machine(tmp_path, text) as (config, daemon, client):
        status = home_all(client, 25.0)
        x = next(a for a in status["axes"] if a["name"] == "X")
        assert -20 <= x["actual_mm"] <= -20 + X_HOME_PAST_MM, x
        assert daemon.controller.link.axis_map.offset_counts[0] == 0  # the drive moved its zero, not the master
        runs_exactly(config, client)
