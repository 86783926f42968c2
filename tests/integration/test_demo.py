"""`nurbsmotion demo`, the README's first command, runs Wang's curve end to end."""

import subprocess
import sys

import pytest

from tests.integration.daemon_helpers import subprocess_environment


@pytest.mark.slow
def test_the_demo_runs_wang_on_simulated_drives_and_writes_its_plot(tmp_path):
    result = subprocess.run([sys.executable, "-m", "nurbsmotion", "demo", "--no-progress", "--data-dir",
                             str(tmp_path / "var")], capture_output=True, text=True, timeout=120, env=subprocess_environment(),
                            cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr[-2000:]
    out = result.stdout
    lines = out.splitlines()
    # homing (simulated limit switch and index pulse), a jog and an MDI move come before the program
    assert lines[1] == "homing Y, X, Z (simulated limit switch and index pulses)"
    assert lines[2].startswith("  axis X: homed by negative limit switch, now at -19.99")
    assert lines[5].startswith("jog X+10 at 20 mm/s: completed, axes at X-9.99")
    assert lines[6] == "MDI G01 X5 Y5 F3000: completed, axes at X5.000 Y5.000 Z0.000"
    assert lines[7].startswith("planned wang_table1.nc")
    assert "outcome: completed" in out and "the drives applied exactly the planned sequence" in out
    plot = next(line.split(": ", 1)[1] for line in out.splitlines() if line.startswith("plot: "))
    with open(plot, "rb") as png:
        assert png.read(8) == b"\x89PNG\r\n\x1a\n"
