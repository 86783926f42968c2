"""scripts/with-vcan itself. Its User-Mode Linux path is what runs this whole directory;
here, where vcan0 is up, it must take the host path, and say why it cannot work otherwise."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY, kernel_timer_threads, timer_threads_below

pytestmark = pytest.mark.vcan

WITH_VCAN = Path(__file__).resolve().parents[2] / "scripts" / "with-vcan"
RUN_TIMEOUT_S = 60.0


def with_vcan(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(WITH_VCAN), *args], capture_output=True, text=True, timeout=RUN_TIMEOUT_S,
                          env=dict(os.environ, **env))


def test_with_vcan0_up_the_command_runs_on_the_host_with_its_output_and_exit_code(vcan0):
    run = with_vcan("sh", "-c", 'echo "out $WITH_VCAN $CALLER_VALUE"; echo err >&2; exit 7',
                    CALLER_VALUE="kept value")

    assert run.returncode == 7
    assert run.stdout == "out host kept value\n"
    assert run.stderr.splitlines() == ["with-vcan: using host vcan0", "err"]


def test_a_command_running_past_the_timeout_is_killed_with_exit_124(vcan0):
    run = with_vcan("--timeout", "1", "sleep", "30")

    assert run.returncode == 124
    assert "did not finish within 1 s" in run.stderr


def test_without_user_mode_linux_it_exits_2_saying_what_to_install():
    run = with_vcan("--uml", "true", WITH_VCAN_UML="/nonexistent/linux.uml")

    assert run.returncode == 2
    assert run.stderr.splitlines() == ["with-vcan: no vcan0 on this host and User-Mode Linux is not installed "
                                       "(apt-get install user-mode-linux kmod)"]


@pytest.mark.parametrize("args", [[], ["--timeout", "soon", "true"], ["--frobnicate", "true"],
                                  ["--softirq-priority", "100", "true"], ["--rt-priority", "high", "true"],
                                  ["--rt-priority"]])
def test_bad_usage_exits_2_with_one_line(args):
    run = with_vcan(*args)

    assert run.returncode == 2
    assert len(run.stderr.splitlines()) == 1 and run.stderr.startswith("with-vcan: ")


@pytest.mark.skipif(os.environ.get("WITH_VCAN") != "uml", reason="the User-Mode Linux guest's set-up")
def test_the_guest_runs_its_soft_timer_threads_above_the_daemons_cycle_thread(vcan0):
    """The kernel queue's SYNC leaves from ksoftirqd under load (runtime.py): in the guest
    with-vcan raises it above the cycle thread, as a real-time machine is set up."""
    assert [t.name for t in kernel_timer_threads()] == ["ksoftirqd/0"]
    assert timer_threads_below(CYCLE_THREAD_PRIORITY) == []
