"""``nurbsmotion drives scan`` and ``drives check --live`` on python-can's virtual bus with
simulated drives: the table, the EDS match, the starting configuration, the live comparison,
and the one-line refusals of bad arguments (exit 2) and of an empty bus (exit 1)."""

from __future__ import annotations

import itertools
import re
import shutil
from pathlib import Path

import pytest

from nurbsmotion.cli import EXIT_BAD_INPUT, EXIT_FAILED, main
from nurbsmotion.config import load_config
from nurbsmotion.sim import SimNetwork

ROOT = Path(__file__).resolve().parents[2]
SERVO = ROOT / "eds" / "nurbsmotion-servo.eds"
EPOS4 = ROOT / "tests" / "data" / "eds" / "maxon_epos4_50_15_node1.dcf"
FAST = ["--listen-ms", "300", "--sdo-timeout-ms", "300"]
_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    return f"drives-scan-{next(_channels)}"


def exit_code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exit_:  # argparse's refusals
        return int(exit_.code or 0)


def test_scan_lists_matches_and_writes_a_configuration_that_loads_once_filled_in(tmp_path, channel, capsys):
    eds_dir = tmp_path / "eds"
    eds_dir.mkdir()
    for source in (SERVO, EPOS4):
        shutil.copy(source, eds_dir)
    out = tmp_path / "machine.yaml"
    with SimNetwork(interface="virtual", channel=channel) as sim:
        sim.add_drive(1)
        sim.add_drive(2, EPOS4)
        sim.add_io_node(10)
        code = main(["drives", "scan", "--interface", "virtual", "--channel", channel, *FAST,
                     "--eds-dir", str(eds_dir), "--write-config", str(out)])
    assert code == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:4] == ["node", "NMT", "device", "type"]
    assert lines[1].split()[:5] == ["1", "PRE-OPERATIONAL", "0x00020192", "CiA", "402"]
    assert re.search(r"  \d+ ms +answers SDO$", lines[1])  # the packaged EDS's heartbeat (0x1017 = 100 ms)
    assert "0x000000FB maxon motor ag  0x65520000  0x01700000  EPOS4" in lines[2]
    assert lines[3].split()[0] == "10" and "0x00030191 CiA 401 I/O, digital in + digital out" in lines[3]
    assert f"node 1: EDS {eds_dir / SERVO.name} (nurbsmotion servo)" in lines
    assert f"node 2: EDS {eds_dir / EPOS4.name} (EPOS4 Module 50/15)" in lines
    assert "node 10: no EDS in" in "\n".join(lines)
    assert any(line.startswith("3 node(s) found on virtual " + channel) for line in lines)
    assert lines[-1].startswith(f"wrote {out}: replace every FILL_IN")
    filled = re.sub(r"(counts_per_mm|soft_limits_mm): FILL_IN",
                    lambda m: f"{m[1]}: {'1000' if m[1] == 'counts_per_mm' else '[-100, 100]'}", out.read_text())
    out.write_text(filled)
    config = load_config(out)
    assert [(a.name, a.node_id, a.mode, Path(a.eds).name) for a in config.axes] == [  # type: ignore[arg-type]
        ("X", 1, "csp", SERVO.name), ("Y", 2, "csp", EPOS4.name)]
    assert config.axes[1].identity is not None and config.axes[1].identity.product_code == 0x65520000
    assert config.io is not None and config.io.node_id == 10


def test_an_empty_bus_is_exit_1_with_one_line(channel, capsys):
    assert main(["drives", "scan", "--interface", "virtual", "--channel", channel, "--listen-ms", "50",
                 "--sdo-timeout-ms", "50"]) == EXIT_FAILED
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"nurbsmotion drives scan: no node found on virtual {channel}")


@pytest.mark.parametrize(("extra", "message"), [
    (["--sdo-timeout-ms", "0"], "argument --sdo-timeout-ms: must be > 0, got 0"),
    (["--listen-ms", "soon"], "argument --listen-ms: not an integer: 'soon'"),
    (["--interface", "udp_multicast"], "--channel x: cannot open udp_multicast x: bus interface 'udp_multicast' is "
                                       "refused: its traffic leaves the machine"),
    (["--interface", "no_such_interface"], "--channel x: cannot open no_such_interface x:"),
    (["--eds-dir", "/nonexistent/eds"], "--eds-dir /nonexistent/eds: not a folder"),
])
def test_bad_arguments_are_one_line_and_exit_2(extra, message, capsys):
    assert exit_code(["drives", "scan", "--interface", "virtual", "--channel", "x", *extra]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and message in err[0], err


def test_an_existing_output_file_is_refused_before_the_bus_is_touched(tmp_path, capsys):
    out = tmp_path / "machine.yaml"
    out.write_text("mine\n")
    assert exit_code(["drives", "scan", "--interface", "no_such_interface", "--write-config", str(out)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"nurbsmotion drives: error: --write-config {out}: exists already: choose another name (nothing was written)"]
    assert out.read_text() == "mine\n"


def machine(tmp_path: Path, channel: str, identity: str = "") -> Path:
    path = tmp_path / "m.yaml"
    path.write_text(f"""\
bus: {{interface: virtual, channel: {channel}}}
axes:
  - {{name: X, node_id: 1, mode: csp}}
  - {{name: Z, node_id: 3, mode: ip{identity}}}
""")
    return path


def test_check_live_passes_on_the_configured_drives(tmp_path, channel, capsys):
    path = machine(tmp_path, channel)
    with SimNetwork.for_machine(load_config(path)):
        assert main(["drives", "check", "--config", str(path), "--live", *FAST]) == 0
    out = capsys.readouterr().out
    assert f"live    {path}:3: axes[0] (X, node 1): OK" in out
    assert f"live    {path}:4: axes[1] (Z, node 3): OK" in out
    assert "live check of virtual " + channel + ": 2 configured node(s), 2 on the bus, 0 error(s)" in out


def test_check_live_names_each_mismatch_and_exits_1(tmp_path, channel, capsys):
    path = machine(tmp_path, channel, identity=", identity: {vendor_id: 0xFB, product_code: 0x65520000}")
    with SimNetwork(interface="virtual", channel=channel) as sim:
        sim.add_drive(3)  # the packaged servo, not the EPOS4 the configuration names; X (node 1) is missing
        sim.add_drive(7)
        assert main(["drives", "check", "--config", str(path), "--live", *FAST]) == EXIT_FAILED
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"nurbsmotion drives: error: {path}:3: axes[0] (X, node 1): not on the bus (no heartbeat, no SDO answer to "
        "0x1000)",
        f"nurbsmotion drives: error: {path}:4: axes[1] (Z, node 3): the node reports vendor 0x00000000 product "
        "0x4E4D0402, identity says vendor 0x000000FB product 0x65520000"]
    assert "warning: node 7 (CiA 402 drive, servo drive) is on the bus but not in the configuration" in captured.out


def test_check_live_covers_the_spindle_and_the_io_node(tmp_path, channel, capsys):
    path = tmp_path / "mill.yaml"
    path.write_text(f"""\
bus: {{interface: virtual, channel: {channel}}}
axes:
  - {{name: X, node_id: 1}}
spindle: {{node_id: 5, mode: csv, counts_per_rev: 4096, max_rpm: 6000, accel_rpm_s: 2000}}
io: {{node_id: 10, inputs: {{estop: {{bit: 0, active_low: true}}}}}}
""")
    with SimNetwork.for_machine(load_config(path)):
        assert main(["drives", "check", "--config", str(path), "--live", *FAST]) == 0
    out = capsys.readouterr().out
    assert f"live    {path}:4: spindle (node 5): OK" in out
    assert f"live    {path}:5: io (node 10): OK" in out


def test_without_an_eds_folder_the_written_configuration_asks_for_the_eds(tmp_path, channel, capsys):
    out = tmp_path / "machine.yaml"
    with SimNetwork(interface="virtual", channel=channel) as sim:
        sim.add_drive(1)
        assert main(["drives", "scan", "--interface", "virtual", "--channel", channel, *FAST,
                     "--write-config", str(out)]) == 0
    assert "    eds: FILL_IN   # the drive's EDS/DCF file (no --eds-dir given)" in out.read_text().splitlines()


def test_check_live_refuses_a_simulated_machine_with_one_line(tmp_path, capsys):
    path = tmp_path / "sim.yaml"
    path.write_text("axes: [{name: X, node_id: 1}]\nsimulate: true\n")
    assert main(["drives", "check", "--config", str(path), "--live"]) == EXIT_BAD_INPUT
    assert capsys.readouterr().err.splitlines() == [
        f"nurbsmotion drives: error: {path}:2: simulate: true: the drives run inside the daemon, there is no bus to "
        "check (--live is for real drives, or `nurbsmotion sim`'s)"]
