"""``nurbsmotion drives check``: the bring-up plan per axis, without a bus; exit 2 with one
line per drive that cannot do what the configuration needs."""

from __future__ import annotations

from pathlib import Path

from nurbsmotion.cli import EXIT_BAD_INPUT, main
from tests.fieldbus.eds_variants import eds_variant

ROOT = Path(__file__).resolve().parents[2]


def test_demo_machine_checks_out_and_lists_what_bring_up_writes(capsys):
    assert main(["drives", "check", "--config", str(ROOT / "config" / "demo.yaml")]) == 0
    out = capsys.readouterr().out
    assert "axis X (node 1): nurbsmotion-servo.eds, cyclic synchronous position (mode 8): OK" in out
    assert "axis Z (node 3): nurbsmotion-servo.eds, interpolated position (mode 7): OK" in out
    assert "write   0x60C2:01 = 4 (Interpolation time period value)" in out
    assert "write   0x1016:01 = 0x007F01F4 (Consumer heartbeat time 1)" in out
    assert "cyclic  RPDO1 (COB-ID 0x201, 6 bytes): controlword 0x6040:00 + setpoint csp 0x607A:00" in out


def test_a_drive_without_the_mode_is_refused_with_one_line(tmp_path, capsys):
    eds_variant(tmp_path, "no_ip.eds", drop=(0x60C1,))
    (tmp_path / "m.yaml").write_text("axes:\n  - {name: X, node_id: 1, mode: csp, eds: no_ip.eds}\n"
                                     "  - {name: Z, node_id: 3, mode: ip, eds: no_ip.eds}\n")
    assert main(["drives", "check", "--config", str(tmp_path / "m.yaml")]) == EXIT_BAD_INPUT
    captured = capsys.readouterr()
    assert "axis X (node 1): no_ip.eds, cyclic synchronous position (mode 8): OK" in captured.out
    err = captured.err.strip().splitlines()
    assert len(err) == 1
    assert err[0].endswith("m.yaml:3: axes[1].mode (Z, node 3): no_ip.eds has no 0x60C1:01, so interpolated "
                           "position (mode 7) is not possible; it offers cyclic synchronous position (mode 8)")


def test_check_shows_the_homing_and_refuses_one_the_eds_cannot_do(tmp_path, capsys):
    eds = ROOT / "tests" / "data" / "eds"
    (tmp_path / "m.yaml").write_text(
        f"axes:\n  - {{name: X, node_id: 1, mode: csp, eds: {eds / 'maxon_epos4_50_15_node1.dcf'},\n"
        f"     homing: {{method: 37, offset_mm: 2}}}}\n")
    assert main(["drives", "check", "--config", str(tmp_path / "m.yaml")]) == 0
    out = capsys.readouterr().out
    assert "  home    method 37: write 0x6098:00 = 37, 0x6060:00 = 6; 0x6061 must read 6" in out
    assert "  home    offset: applied by the master (the drive has no 0x607C): offset_counts -2000" in out
    (tmp_path / "m.yaml").write_text(f"axes:\n  - {{name: X, node_id: 1, mode: ip, eds: {eds / 'schunk_PRL120.eds'},"
                                     f"\n     homing: {{method: 35}}}}\n")
    assert main(["drives", "check", "--config", str(tmp_path / "m.yaml")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("m.yaml:3: axes[0].homing.method (X, node 1): schunk_PRL120.eds has no "
                                             "0x6098:00 (homing method), needed for homing method 35; use method: here")


def test_missing_action_is_exit_2(capsys):
    try:
        code = main(["drives"])
    except SystemExit as exit_:
        code = exit_.code
    assert code == EXIT_BAD_INPUT
