"""Homing methods 1, 2, 17, 18, 33 and 34 through a ``simulate: true`` daemon (this process,
private virtual bus) whose simulated drives take their limit switches and index pulses from
the YAML (``axes[i].sim``), nothing given in code: each axis must be homed where its YAML
says the switch edge or index pulse is."""

from __future__ import annotations

import tempfile
import uuid
from pathlib import Path

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.service.client import Client
from nurbsmotion.service.daemon import Daemon
from tests.integration.daemon_helpers import CONFIG_HEAD, home_all

CONFIG = CONFIG_HEAD + """\
axes:
{axes}
control: {{socket: {socket}}}
data_dir: {data_dir}
"""
AXIS = """\
  - {{name: {name}, node_id: {node}, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100], invert: {invert},
     max_velocity_mm_s: 200, max_accel_mm_s2: 2000, following_error_window_mm: 2.0,
     homing: {{method: {method}, speed_search_mm_s: 20, speed_zero_mm_s: 2, accel_mm_s2: 200}},
     sim: {sim}}}
"""
SWITCH_EDGE_COUNTS = 10  # a switch is sampled once per cycle at speed_zero: 2 mm/s x 4 ms = 8 counts (docs/machine.md)
# (axis, method, invert, sim section, raw counts of the home, how exact)
CASES = {
    "1 2 17": [("X", 1, False, "{negative_limit_mm: -3, index_pitch_mm: 2, index_phase_mm: 0.7}", -1300, 1),
               ("Y", 2, False, "{positive_limit_mm: 4, index_pitch_mm: 2.5}", 2500, 1),
               ("Z", 17, True, "{positive_limit_mm: 2}", -2000, SWITCH_EDGE_COUNTS)],  # inverted: drive's negative
    "18 33 34": [("X", 18, False, "{positive_limit_mm: 3}", 3000, SWITCH_EDGE_COUNTS),
                 ("Y", 33, False, "{index_pitch_mm: 1.5, index_phase_mm: 0.2}", -1300, 1),
                 ("Z", 34, False, "{index_pitch_mm: 1.5, index_phase_mm: 0.2, negative_limit_mm: -50}", 200, 1)],
}


@pytest.mark.parametrize("methods", sorted(CASES))
def test_drives_home_on_the_switches_and_index_pulses_of_the_yaml(tmp_path: Path, methods: str):
    cases = CASES[methods]
    folder = Path(tempfile.mkdtemp(prefix="nm-"))
    axes = "".join(AXIS.format(name=n, node=i + 1, method=m, invert=str(inv).lower(), sim=sim)
                   for i, (n, m, inv, sim, _, _) in enumerate(cases))
    config = parse_config(CONFIG.format(channel=f"hy-{uuid.uuid4().hex}", axes=axes.rstrip("\n"),
                                        socket=folder / "ctl.sock", data_dir=tmp_path / "data"), "machine.yaml")
    daemon = Daemon(config)  # the daemon's own open_link: sensors from the YAML only
    daemon.start()
    try:
        with Client(config.control.socket) as client:
            status = home_all(client, 60.0)
            assert set(status["homing"]["axes"].values()) == {"homed"}
            for i, (name, method, _, _, home_counts, exact) in enumerate(cases):
                drive = daemon.simulation.network[i + 1]
                found = -drive.axis.home_shift  # offset 0: the home reads 0, so raw home = -shift
                assert abs(found - home_counts) <= exact, (name, method, found)
                assert abs(status["axes"][i]["commanded_mm"]) <= 0.02  # rests where it stopped, near 0 mm
    finally:
        daemon.close()
