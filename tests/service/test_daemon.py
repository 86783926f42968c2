"""The daemon object in this process (fake link): what clients see while it starts and ends."""

import threading
import time
from pathlib import Path

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.service.client import Client, DaemonUnavailable
from nurbsmotion.service.daemon import Daemon
from nurbsmotion.service.records import JobRecords
from tests.service.fakes import FakeLink, with_data_dir

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def config(tmp_path):
    return with_data_dir(load_config(ROOT / "config" / "demo.yaml"), str(tmp_path / "data"), str(tmp_path / "ctl.sock"))


def _daemon(config, cycle_s=0.002):
    links = []

    def open_motion(cfg):
        links.append(FakeLink(cfg, cycle_s))
        return links[0], None
    return Daemon(config, open_motion), links


def test_clients_polling_while_the_daemon_ends_mid_job_never_see_an_internal_error(config):
    """Issue 15.8: ``run`` printed ``internal error: AssertionError`` when the daemon got
    SIGTERM during a job (the handler asserted the controller while it was torn down)."""
    daemon, _ = _daemon(config)
    daemon.start()
    responses: list[dict] = []
    ended = threading.Event()

    def poll() -> None:  # what `run` does: status until the job ends, then the job's record
        try:
            with Client(config.control.socket, timeout_s=5.0) as client:
                while not ended.is_set():
                    responses.append(client.request("status"))
                    responses.append(client.request("job", id=job_id))
        except DaemonUnavailable:
            pass

    try:
        job_id = daemon.controller.submit("long.nc", "G21 G90\nG01 X20 F600\n")["job"]["id"]
        poller = threading.Thread(target=poll)
        poller.start()
        time.sleep(0.1)
    finally:
        daemon.close()
        ended.set()
    poller.join(5.0)
    errors = [r["error"] for r in responses if not r.get("ok")]
    assert responses and not [e for e in errors if "internal error" in e], errors
    assert all("shutting down" in e for e in errors), errors
    assert JobRecords(config.data_dir).find(job_id).outcome()["outcome"] == "stopped"


def test_the_socket_answers_only_once_the_controller_exists_and_not_after_close(config):
    daemon, _ = _daemon(config)
    with pytest.raises(DaemonUnavailable):
        Client(config.control.socket).connect()
    daemon.start()
    try:
        with Client(config.control.socket) as client:
            assert client.request("status")["state"] == "idle"
    finally:
        daemon.close()
    with pytest.raises(DaemonUnavailable):
        Client(config.control.socket).connect()


def test_a_corrupt_offsets_file_stops_the_start_with_one_line_naming_file_and_field(config):
    from nurbsmotion.errors import InputError
    from nurbsmotion.service.machine_state import state_path

    Path(config.data_dir).mkdir(parents=True)
    state_path(config.data_dir).write_text('{"format": 1, "coordinates": {"g92_mm": [1, "x", 3]}}')
    daemon, links = _daemon(config)
    with pytest.raises(InputError) as err:
        daemon.start()
    assert str(err.value) == (f"{state_path(config.data_dir)}: coordinates.g92_mm: must be 3 finite numbers "
                              "[x, y, z] in mm, got [1, 'x', 3]")
    assert links == [] and not Path(config.control.socket).exists()  # nothing was started
    daemon.close()


def test_the_planner_worker_is_ready_before_the_bus_starts(config):
    """The planner worker's interpreter imports the planner before the bus and the cycle
    thread start: spawned after bring-up it competed with them and with the drives for the
    CPU (inside User-Mode Linux, one CPU: first motion 13 s after the first submission and
    the drives' process seconds behind its socket), and the first job waited for it."""
    seen: list[tuple[bool, bool]] = []

    def open_motion(cfg):
        worker = daemon.planner_worker
        seen.append((worker is not None and worker.alive, worker is not None and worker.ready))
        return FakeLink(cfg, 0.002), None

    daemon = Daemon(config, open_motion)
    daemon.start()
    try:
        assert seen == [(True, True)]
    finally:
        daemon.close()
    assert daemon.planner_worker is None


def test_a_bus_that_fails_to_open_stops_the_planner_worker_too(config):
    workers = []

    def open_motion(cfg):
        workers.append(daemon.planner_worker)
        raise OSError("no such device: vcan9")

    daemon = Daemon(config, open_motion)
    with pytest.raises(OSError):
        daemon.start()
    assert daemon.planner_worker is None and workers and not workers[0].alive
