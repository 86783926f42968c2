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
    assert "outcome: completed" in out and "the drives applied exactly the planned sequence" in out
    plot = next(line.split(": ", 1)[1] for line in out.splitlines() if line.startswith("plot: "))
    with open(plot, "rb") as png:
        assert png.read(8) == b"\x89PNG\r\n\x1a\n"
