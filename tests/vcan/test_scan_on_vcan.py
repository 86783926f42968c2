"""`nurbsmotion drives scan` and `drives check --live` on a real kernel SocketCAN vcan0, as an
integrator runs them: `nurbsmotion sim` (config/vcan.yaml's three drives) in one process, two
nodes that answer partly in the test's process (a heartbeat without an SDO server; 0x1000
answered but 0x1018 refused), and the commands as a third process."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import canopen
import pytest

import nurbsmotion
from tests.fieldbus.fake_nodes import ABORT_HARDWARE, FakeNode

pytestmark = pytest.mark.vcan

ROOT = Path(__file__).resolve().parents[2]
VCAN_CONFIG = ROOT / "config" / "vcan.yaml"
# The drives' process inside User-Mode Linux answers SDOs up to seconds late on a busy host
# (config/vcan.yaml's bus.sdo_timeout_ms is 3000 for that reason); real drives: milliseconds.
SLOW_GUEST = ["--listen-ms", "1000", "--sdo-timeout-ms", "3000"]
COMMAND_TIMEOUT_S = 120


def nurbsmotion_command(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(Path(nurbsmotion.__file__).parents[1]))
    return subprocess.run([sys.executable, "-m", "nurbsmotion", *args], capture_output=True, text=True, env=env,
                          timeout=COMMAND_TIMEOUT_S, cwd=ROOT)


def test_scan_and_live_check_on_vcan0(vcan0, sim_process, tmp_path):
    sim_process(VCAN_CONFIG)
    network = canopen.Network()
    network.connect(interface="socketcan", channel=vcan0)
    nodes = [FakeNode(network, 20, sdo=False, heartbeat_state=0x7F, heartbeat_period_s=0.2),
             FakeNode(network, 21, {(0x1000, 0): 0x00030191, (0x1018, 1): ("abort", ABORT_HARDWARE)})]
    out = tmp_path / "machine.yaml"
    try:
        scan = nurbsmotion_command("drives", "scan", "--interface", "socketcan", "--channel", vcan0, *SLOW_GUEST,
                                   "--eds-dir", str(ROOT / "eds"), "--write-config", str(out))
        live = nurbsmotion_command("drives", "check", "--config", str(VCAN_CONFIG), "--live", "--listen-ms", "1000")
    finally:
        for node in nodes:
            node.close()
        network.disconnect()
    print(scan.stdout, scan.stderr, live.stdout, live.stderr, sep="\n")
    assert scan.returncode == 0, scan.stderr
    rows = {m[1]: m[0] for m in (re.match(r"(\d+)\s{2,}.*", line) for line in scan.stdout.splitlines()) if m}
    assert sorted(rows, key=int) == ["1", "2", "3", "20", "21"]
    for node in ("1", "2", "3"):
        assert "0x00020192 CiA 402 drive, servo drive" in rows[node] and "pv hm ip csp csv" in rows[node]
        assert f"node {node}: EDS {ROOT / 'eds' / 'nurbsmotion-servo.eds'} (nurbsmotion servo)" in scan.stdout
    assert rows["20"].split()[1] == "PRE-OPERATIONAL" and rows["20"].endswith("heartbeat only: no SDO answer")
    assert "0x00030191 CiA 401 I/O, digital in + digital out" in rows["21"]
    assert "node 21: 0x1018:01 (vendor id): SDO abort 0x06060000 (Access failed due to a hardware error)" in scan.stdout
    assert out.read_text().count("\n  - name: ") == 3  # one axis per simulated drive
    assert live.returncode == 0, live.stderr
    for i, (name, node) in enumerate((("X", 1), ("Y", 2), ("Z", 3))):
        assert f"axes[{i}] ({name}, node {node}): OK" in live.stdout
    assert "warning: node 20 (heartbeat only: no SDO answer) is on the bus but not in the configuration" in live.stdout
