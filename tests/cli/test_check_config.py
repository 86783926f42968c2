"""``nurbsmotion check --config``: the machine's axes, limits and soft limits apply."""

import json
from pathlib import Path

from nurbsmotion.cli import main

ROOT = Path(__file__).resolve().parents[2]
DEMO = str(ROOT / "config" / "demo.yaml")  # X, Y, Z with soft limits [-200, 200]
XY_ONLY = "axes:\n  - {name: X, node_id: 1, counts_per_mm: 100}\n  - {name: Y, node_id: 2, counts_per_mm: 100}\n"


def test_a_program_beyond_the_soft_limit_passes_alone_and_fails_on_the_machine(tmp_path, capsys):
    part = tmp_path / "part.nc"
    part.write_text("G21 G90\nG01 X10 F3000\nG01 X250\n")
    assert main(["check", str(part)]) == 0
    capsys.readouterr()
    assert main(["check", "--config", DEMO, str(part)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nurbsmotion check: error: {part}:3: X250: axis X would reach 250 mm, "
                   f"beyond the soft limit 200 mm"]


def test_the_start_position_counts(tmp_path, capsys):
    part = tmp_path / "part.nc"
    part.write_text("G21 G91\nG01 X60 F3000\n")  # incremental: from X150 it ends at X210
    assert main(["check", "--config", DEMO, "--start", "150", "0", "0", str(part)]) == 2
    assert "part.nc:2: axis X would reach 210 mm" in capsys.readouterr().err


def test_a_program_moving_an_axis_the_machine_lacks_is_refused(tmp_path, capsys):
    part, config = tmp_path / "part.nc", tmp_path / "xy.yaml"
    part.write_text("G21 G90\nG01 X10 Z5 F3000\n")
    config.write_text(XY_ONLY)
    assert main(["check", "--config", str(config), "--json", str(part)]) == 2
    errors = json.loads(capsys.readouterr().out)["errors"]
    assert errors == [{"where": str(part), "message": "the program moves Z, which this machine has no axis for"}]


def test_a_good_program_reports_the_machine(tmp_path, capsys):
    part = tmp_path / "part.nc"
    part.write_text("G21 G90\nG01 X10 Y5 F3000\n")
    assert main(["check", "--config", DEMO, str(part)]) == 0
    assert f"machine   {DEMO}: axes X Y Z, within the axis and soft limits" in capsys.readouterr().out
    assert main(["check", "--config", DEMO, "--json", str(part)]) == 0
    machine = json.loads(capsys.readouterr().out)["machine"]
    assert machine["axes"] == ["X", "Y", "Z"] and machine["cycles"] > 10


def test_the_machine_gate_tool_table_and_persisted_offsets_apply(tmp_path, capsys):
    """check --config reads as the daemon does: the config's tool table, DATA_DIR/offsets.json,
    and what the machine lacks (spindle: none) refuses the program at its line."""
    from nurbsmotion.service.machine_state import MachineState, save_state, with_offset

    (tmp_path / "tools.yaml").write_text("tools:\n  - {number: 4, length_mm: 150, diameter_mm: 6}\n")
    config = tmp_path / "m.yaml"
    config.write_text(Path(DEMO).read_text().replace("data_dir:", "#") + f"data_dir: {tmp_path / 'data'}\n"
                      "tools: tools.yaml\nspindle: none\n")
    save_state(tmp_path / "data", with_offset(MachineState(), "G54", (100.0, 0.0, 0.0)))
    part = tmp_path / "part.nc"
    part.write_text("G21 G90\nG43 H4\nG01 X10 Z0 F3000\nM3 S9000\n")
    assert main(["check", "--config", str(config), str(part)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"nurbsmotion check: error: {part}:4: M3 needs a spindle, and this machine has none (spindle: none in {config})"]
    part.write_text("G21 G90\nG43 H4\nG01 X10 Z0 F3000\n")  # machine X 110, Z 150: within the limits
    assert main(["check", "--config", str(config), "--json", str(part)]) == 0
    assert json.loads(capsys.readouterr().out)["end_mm"] == [110.0, 0.0, 150.0]
    part.write_text("G21 G90\nG43 H4\nG01 X10 Z60 F3000\n")  # machine Z 210: beyond
    assert main(["check", "--config", str(config), str(part)]) == 2
    assert "part.nc:3: axis Z would reach 210 mm, beyond the soft limit 200 mm" in capsys.readouterr().err


def test_a_program_starting_with_a_byte_order_mark_is_read_by_every_command(tmp_path, capsys):
    """CAM posts and Windows editors write a UTF-8 BOM (tests/data/gcode/textbook_simple_mill.gcode
    has one): it is not part of line 1 for check, check --config, plan or what run submits."""
    from nurbsmotion.text_files import read_text_file

    part = tmp_path / "part.nc"
    part.write_bytes(b"\xef\xbb\xbfG21 G90\nG01 X10 F3000\n")
    assert main(["check", str(part)]) == 0
    assert main(["check", "--config", DEMO, str(part)]) == 0
    assert main(["plan", "--config", DEMO, str(part)]) == 0
    assert not read_text_file(str(part)).startswith("\ufeff")  # what run submits
    assert "\ufeff" not in capsys.readouterr().err


def test_run_of_a_binary_file_says_what_check_says(tmp_path, capsys):
    """One message for a file that is not text, whichever command reads it (issue 26.6)."""
    part = tmp_path / "part.nc"
    part.write_bytes(b"G21\n\x89PNG\r\n\x1a\n\xff\xfe")
    assert main(["check", str(part)]) == 2
    checked = capsys.readouterr().err
    assert main(["run", str(part), "--socket", str(tmp_path / "none.sock")]) == 2  # refused before any daemon
    ran = capsys.readouterr().err
    assert checked.replace("nurbsmotion check", "") == ran.replace("nurbsmotion run", "")
    assert ran == f"nurbsmotion run: error: {part}: not a UTF-8 text file (invalid start byte at byte 4)\n"
