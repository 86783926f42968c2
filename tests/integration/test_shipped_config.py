"""The README's commands work with the shipped configuration (issue 26.6): ``nurbsmotion
home`` with config/demo.yaml homes every axis on the simulated drives' switches and index
pulses that its ``sim:`` sections place, nothing injected in code (the demo used to)."""

from __future__ import annotations

import dataclasses
import tempfile
import uuid
from pathlib import Path

from nurbsmotion.config import load_config
from nurbsmotion.service.client import Client
from nurbsmotion.service.daemon import Daemon
from tests.helpers import wait_for

ROOT = Path(__file__).resolve().parents[2]


def test_home_with_the_demo_configuration_homes_every_axis(tmp_path: Path):
    shipped = load_config(ROOT / "config" / "demo.yaml")
    assert all(axis.homing is not None for axis in shipped.axes)
    folder = Path(tempfile.mkdtemp(prefix="nm-"))
    config = dataclasses.replace(  # only what keeps the test private: its bus channel, socket and records
        shipped, bus=dataclasses.replace(shipped.bus, channel=f"shipped-{uuid.uuid4().hex}"),
        control=dataclasses.replace(shipped.control, socket=str(folder / "ctl.sock")), data_dir=str(tmp_path))
    daemon = Daemon(config)  # the daemon's own open_link: the switches come from the YAML's sim sections
    daemon.start()
    try:
        with Client(config.control.socket) as client:
            assert client.call("home")["axes"] == ["Y", "X", "Z"]
            wait_for(lambda: not client.call("status")["homing"]["busy"], 60.0, "the homing to end", poll_s=0.05)
            status = client.call("status")
    finally:
        daemon.close()
    assert status["homing"]["error"] is None
    assert status["homing"]["axes"] == {"X": "homed", "Y": "homed", "Z": "homed"}
    at = {a["name"]: a["commanded_mm"] for a in status["axes"]}
    assert abs(at["X"] + 20.0) <= 0.02  # on the limit switch at -20 mm, which the home offset makes -20 mm
