"""Run ``python -m nurbsmotion daemon`` as a subprocess with in-process simulated drives on a
private virtual bus, a private socket and a private data directory."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path
from collections.abc import Iterator
from typing import Any

import pytest

import nurbsmotion
from nurbsmotion.config import MachineConfig, load_config
from nurbsmotion.service.client import Client, DaemonUnavailable
from tests.helpers import wait_for

SRC_DIR = Path(nurbsmotion.__file__).resolve().parents[1]
START_TIMEOUT_S = 20.0

CONFIG_HEAD = """\
cycle_period_ms: 4
simulate: true
bus: {{interface: virtual, channel: {channel}}}
interpolation: {{algorithm: lookahead, feed_mm_min: 3000, chord_error_mm: 0.01, max_accel_mm_s2: 1000,
                max_jerk_mm_s3: 50000, acc_time_s: 0.1}}
"""  # the machine without its axes: CONFIG's, or a test's own
CONFIG = CONFIG_HEAD + """\
axes:
  - {{name: X, node_id: 1, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100],
     max_velocity_mm_s: 200, max_accel_mm_s2: 2000, following_error_window_mm: 2.0}}
  - {{name: Y, node_id: 2, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100],
     max_velocity_mm_s: 200, max_accel_mm_s2: 2000, following_error_window_mm: 2.0}}
  - {{name: Z, node_id: 3, mode: ip, counts_per_mm: 1000, soft_limits_mm: [-100, 100],
     max_velocity_mm_s: 200, max_accel_mm_s2: 2000, following_error_window_mm: 2.0}}
monitoring: {{traffic_log: log}}
control: {{socket: {socket}}}
data_dir: {data_dir}
"""


def home_all(client: Any, timeout_s: float) -> dict[str, Any]:
    """``home`` every axis, wait until the homing ended; the status then, its homing without error."""
    assert client.call("home")["ok"]
    wait_for(lambda: not client.call("status")["homing"]["busy"], timeout_s, "the homing to end", poll_s=0.05)
    status = client.call("status")
    assert status["homing"]["error"] is None, status["homing"]
    return status


@contextlib.contextmanager
def daemon_in_process(data_dir: Path, extra_yaml: str, prefix: str) -> Iterator[Any]:
    """A started service.daemon.Daemon (this process) on CONFIG + ``extra_yaml``, a private
    virtual channel and socket; closed at the end."""
    from nurbsmotion.service.daemon import Daemon

    folder = Path(tempfile.mkdtemp(prefix="nm-"))
    path = folder / "machine.yaml"
    path.write_text(CONFIG.format(channel=f"{prefix}-{uuid.uuid4().hex}", socket=folder / "ctl.sock",
                                  data_dir=data_dir) + extra_yaml)
    daemon = Daemon(load_config(path))
    daemon.start()
    try:
        yield daemon
    finally:
        daemon.close()


@contextlib.contextmanager
def daemon_with_home_sensors(config_template: str, prefix: str, sensors: dict[int, Any],
                             **fields: Any) -> Iterator[tuple[Any, Any]]:
    """The daemon (this process) on ``config_template`` formatted with a private channel,
    socket and data dir (and ``fields``), its simulated drives given home ``sensors``, and a
    client; both closed at the end."""
    import functools

    from nurbsmotion.config import parse_config
    from nurbsmotion.service.daemon import Daemon
    from nurbsmotion.service.link import open_link

    folder = Path(tempfile.mkdtemp(prefix=f"nm-{prefix}-"))
    config = parse_config(config_template.format(channel=f"{prefix}-{uuid.uuid4().hex}", socket=folder / "ctl.sock",
                                                 data_dir=folder / "data", **fields), "machine.yaml")
    daemon = Daemon(config, functools.partial(open_link, home_sensors=sensors))
    daemon.start()
    try:
        with Client(config.control.socket) as client:
            yield daemon, client
    finally:
        daemon.close()


def job_reached(status: dict[str, Any], fraction: float) -> bool:
    """The running job (in a ``status`` answer) has sent ``fraction`` of its planned set-points.

    A streamed job's ``total`` is the rows planned so far until ``planned_all`` (docs/daemon.md,
    "Status while a job is planned"): right after the start that is cycle 1 of 1, so a fraction
    of it is not a fraction of the job; the job's length is known once it is all planned."""
    job = status["job"]
    return job is not None and job["planned_all"] and job["cycle"] >= fraction * job["total"]


def subprocess_environment(notify_socket: Path | None = None) -> dict[str, str]:
    """This test's nurbsmotion first on the path; $NOTIFY_SOCKET only if given."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(SRC_DIR), env.get("PYTHONPATH", "")) if p)
    env.pop("NOTIFY_SOCKET", None)
    if notify_socket is not None:
        env["NOTIFY_SOCKET"] = str(notify_socket)
    return env


class DaemonProcess:
    """The daemon subprocess and its files; ``close()`` always ends it."""

    def __init__(self, data_dir: Path) -> None:
        self.folder = Path(tempfile.mkdtemp(prefix="nm-"))  # short: AF_UNIX paths are <= 107 bytes
        self.socket = self.folder / "ctl.sock"
        self.data_dir = data_dir
        self.config_path = self.folder / "machine.yaml"
        self.config_path.write_text(CONFIG.format(channel=f"it-{uuid.uuid4().hex}", socket=self.socket,
                                                  data_dir=data_dir))
        self.config: MachineConfig = load_config(self.config_path)
        self.log_path = self.folder / "daemon.log"
        self.proc: subprocess.Popen[bytes] | None = None
        self.notify_socket: Path | None = None  # set: the daemon gets it as $NOTIFY_SOCKET
        self.verbose = ["-v"]  # [] runs it as a user would (INFO by default as well)

    def environment(self) -> dict[str, str]:
        return subprocess_environment(self.notify_socket)

    def start(self) -> "DaemonProcess":
        with open(self.log_path, "wb") as log:
            self.proc = subprocess.Popen([sys.executable, "-m", "nurbsmotion", *self.verbose, "daemon", "--config",
                                          str(self.config_path)], stdout=log, stderr=subprocess.STDOUT,
                                         env=self.environment())
        wait_for(self._answers, START_TIMEOUT_S, "the daemon to answer on its socket", poll_s=0.05)
        return self

    def _answers(self) -> bool:
        assert self.proc is not None
        if self.proc.poll() is not None:
            raise AssertionError(f"daemon exited with {self.proc.returncode}: {self.log()[-2000:]}")
        try:
            with Client(self.socket, timeout_s=5.0) as client:
                return bool(client.request("status").get("ok"))
        except DaemonUnavailable:
            return False

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def request(self, cmd: str, **fields: Any) -> dict[str, Any]:
        with Client(self.socket, timeout_s=30.0) as client:
            return client.request(cmd, **fields)

    def wait_job_end(self, job_id: str, timeout_s: float = 20.0) -> dict[str, Any]:
        def ended() -> dict[str, Any] | None:
            job = self.request("job", id=job_id)["job"]
            return job if job["outcome"] is not None else None
        return wait_for(ended, timeout_s, f"the end of job {job_id}", poll_s=0.05)

    def wait_progress(self, fraction: float, timeout_s: float = 20.0) -> dict[str, Any]:
        """The status once the running job has sent ``fraction`` of its set-points; a job seen
        running that ends before it fails at once, naming the machine's faults (not a time-out)."""
        seen_job = False

        def reached() -> dict[str, Any] | None:
            nonlocal seen_job
            status = self.request("status")
            if status["job"] is None and seen_job:
                raise AssertionError(f"the job ended before {fraction:.0%}: state {status['state']}, "
                                     f"faults {status.get('faults')}")
            seen_job = seen_job or status["job"] is not None
            return status if job_reached(status, fraction) else None
        return wait_for(reached, timeout_s, f"{fraction:.0%} of the job", poll_s=0.01)

    def close(self, timeout_s: float = 15.0) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    """One daemon process (simulated drives) for a whole test module; always closed."""
    proc = DaemonProcess(tmp_path_factory.mktemp("data"))
    try:
        yield proc.start()
    finally:
        proc.close()
