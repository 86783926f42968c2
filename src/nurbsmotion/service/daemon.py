"""The daemon: drives up, job records checked, control socket served until SIGTERM/SIGINT.

Start-up order: the bus and the control socket are ours (service.ownership: else one line
naming the other daemon, nothing touched) -> mark jobs left without outcome 'interrupted' ->
the persisted offsets (DATA_DIR/offsets.json; unreadable: one error, nothing started) ->
simulated drives (if configured) -> bring-up of every axis -> control socket -> READY=1
(systemd). Shutdown
order: refuse new jobs (and every request that would move or re-enable something) ->
controlled stop of a running job (outcome 'stopped') -> drives disabled -> socket removed
-> simulated drives stopped. The socket keeps answering ``status`` and ``job`` until it is
removed, so a client following the job sees its outcome, never an internal error.
"""

from __future__ import annotations

import logging
import signal
import threading
from typing import Any, Callable

import numpy as np

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError, Refused
from nurbsmotion.fieldbus.cycle_slack import run_steps
from nurbsmotion.steps import Steps
from nurbsmotion.log import kv
from nurbsmotion.program import ReadOptions
from nurbsmotion.runtime import STATUS_PUBLISHER_PRIORITY, cap_switch_interval, reserve_realtime_cpu
from nurbsmotion.service.checked_store import CheckedStore
from nurbsmotion.service.controller import Controller
from nurbsmotion.service.devices import open_devices
from nurbsmotion.service.job_queue import JobQueue
from nurbsmotion.service.link import open_link
from nurbsmotion.service.machine_state import load_state
from nurbsmotion.service.motion import MotionLink, Simulation
from nurbsmotion.service.notify import sd_notify
from nurbsmotion.service.ownership import BusOwnership
from nurbsmotion.service.planner import needs_planner_worker, prepare_job
from nurbsmotion.service.planner_worker import PlannerWorker
from nurbsmotion.service.program_file import ProgramFile, clear_spool, requested_program
from nurbsmotion.service.programs import LIBRARY_COMMANDS, Programs
from nurbsmotion.service.protocol import MAX_REQUEST_BYTES, EncodedResponse, Request, encode_steps
from nurbsmotion.service.records import JobRecords
from nurbsmotion.service.server import ControlServer
from nurbsmotion.service.start_line import start_line_field
from nurbsmotion.service.subscriptions import StatusHub, attach_event_log
from nurbsmotion.service.webhooks import start_webhooks

log = logging.getLogger(__name__)

ANSWERED_WHILE_CLOSING = frozenset({"status", "job", "jobs", "stop", "abort", "jog_stop"})  # read, or stop sooner


def dispatch(controller: Controller, request: Request, programs: Programs | None = None) -> dict[str, Any]:
    """Route one checked request to the controller (the library and queue: to ``programs``)."""
    f = request.fields
    if programs is not None and request.cmd in LIBRARY_COMMANDS:
        return programs.handlers(request)[request.cmd]()
    handlers: dict[str, Callable[[], dict[str, Any]]] = {
        "submit": lambda: submit(controller, request),
        "mdi": lambda: controller.mdi(f["text"]),
        "offsets": lambda: controller.offsets(f),
        "status": lambda: status_answer(controller, programs),
        "job": lambda: controller.job_info(f["id"]),
        "jobs": lambda: controller.jobs(int(f.get("limit", 20))),
        "stop": controller.stop,
        "abort": controller.abort,
        "hold": controller.hold,
        "resume": controller.resume,
        "reset": controller.reset,
        "override": lambda: controller.override(float(f["percent"])),
        "inject_fault": lambda: controller.inject_fault(f["spec"]),
        "home": lambda: controller.home(f.get("axes", "").replace(",", " ").split()),
        "jog": lambda: controller.jogging.jog(f),
        "jog_renew": controller.jogging.renew,
        "jog_stop": controller.jogging.stop,
    }
    if request.cmd not in handlers:
        raise Refused(request.cmd, "this daemon has no program library")
    return handlers[request.cmd]()


def submit(controller: Controller, request: Request) -> dict[str, Any]:
    """``submit``: the program's text, or the file sent along (service.program_file: spooled
    while the job starts, never read into the daemon)."""
    f = request.fields
    with requested_program(f, request.files, controller.config.data_dir, MAX_REQUEST_BYTES,
                           "a request's, the text's limit as well") as program:
        return controller.submit(f["name"], program, bool(f.get("keep_override", False)),
                                 bool(f.get("block_delete", True)), bool(f.get("optional_stop", True)),
                                 start_line=start_line_field(f.get("start_line")))


def status_answer(controller: Controller, programs: Programs | None) -> EncodedResponse:
    """``status``: read and encoded in the cycle thread's slack while it runs
    (fieldbus.cycle_slack), so a poller (the CLI, a pendant, a dashboard) never holds the
    interpreter lock when the cycle thread wakes (a status encoded in the request's thread
    was there at a tenth of the late wake-ups of a job with a poller, docs/web.md); the job
    queue's summary is added in the request's thread (it takes the queue's lock), the send
    stays there."""
    slack = controller.link.cycle_slack
    answer = EncodedResponse(with_queue(run_steps(controller.status_steps(), slack), programs))
    answer.line = run_steps(encode_steps(answer), slack)
    return answer


def with_queue(status: dict[str, Any], programs: Programs | None) -> dict[str, Any]:
    """The status with the job queue's summary (service.job_queue)."""
    if programs is not None:
        status["queue"] = programs.queue.summary()
    return status


class Daemon:
    """Everything the daemon runs, started by :meth:`start` and ended by :meth:`close`."""

    def __init__(self, config: MachineConfig,
                 open_motion: Callable[[MachineConfig], tuple[MotionLink, Simulation | None]] = open_link) -> None:
        self.config = config
        self._open_motion = open_motion
        self.records = JobRecords(config.data_dir)
        self.controller: Controller | None = None
        self.server: ControlServer | None = None
        self.simulation: Simulation | None = None
        self._closing = False
        self.ownership = BusOwnership(config)
        self.planner_worker: PlannerWorker | None = None  # plans streamed jobs in its own process
        self.hub: StatusHub | None = None  # pushes status and events to subscribed clients
        self._detach_event_log: Callable[[], None] | None = None
        self._stop_webhooks: Callable[[], None] | None = None
        self.store = CheckedStore.for_config(config)  # checked programs (service.checked_store)
        self.programs: Programs | None = None  # the program library and job queue

    def start(self) -> None:
        self.ownership.acquire()  # before the first frame and before touching the job records (BusTaken)
        cap_switch_interval(self.config.cycle_period_s)  # process-wide: the cycle thread gets the GIL in time
        for record in self.records.mark_interrupted():
            log.warning(kv("job_interrupted", job=record.job_id, folder=record.folder))
        clear_spool(self.config.data_dir)  # a daemon that died mid-start left its spooled programs
        machine_state = load_state(self.config.data_dir)  # a corrupt offsets.json: one error, nothing started
        queue = JobQueue(self.config.data_dir)  # a corrupt queue.json too
        self._start_planner_worker()
        try:
            link, self.simulation = self._open_motion(self.config)
        except BaseException:
            self._stop_planner_worker()
            raise
        try:
            devices = open_devices(self.config, link)  # spindle and I/O node, after the axes
        except BaseException:
            link.shutdown(2.0)
            self._stop_simulation()
            self._stop_planner_worker()
            raise
        self.controller = Controller(self.config, link, self._prepare_job, self.records, self.simulation, machine_state,
                                     devices)
        self.programs = Programs(self.config, self.controller, self.store, queue)
        self.hub = StatusHub(self._status, read_fast=self._fast_status, realtime_priority=STATUS_PUBLISHER_PRIORITY,
                             next_cycle_wake_s=link.next_cycle_wake_s, slack=link.cycle_slack)
        self._detach_event_log = attach_event_log(self.hub)
        self._stop_webhooks = start_webhooks(self.config.notify, self.config.source)
        # the library pruned and the queue runner going before the socket answers: a request never
        # meets a half-started daemon, and the first answer comes with daemon_ready logged
        self.programs.start()
        self.server = ControlServer(self.config.control.socket, self._handle, self.config.control.group, hub=self.hub)
        try:
            self.server.start()
        except BaseException:
            self._stop_motion()
            raise
        sd_notify("READY=1")
        log.info(kv("daemon_ready", socket=self.config.control.socket, simulate=self.config.simulate))

    def _start_planner_worker(self) -> None:
        """Spawn the planner worker and wait for its imports before the bus starts: started
        later, a fresh interpreter's imports compete for the CPU with the cycle thread and
        (simulated) drives already running, and the first job waits for them (inside
        User-Mode Linux, one CPU: 13 s to the first motion, drives lagging seconds behind).
        A worker that is not ready in time is waited for again by the first job."""
        if not needs_planner_worker(self.config):
            return
        self.planner_worker = PlannerWorker()
        self.planner_worker.start()
        try:
            self.planner_worker.wait_ready()
        except InputError as err:
            log.warning(kv("planner_worker_not_ready", error=err))

    def _prepare_job(self, name: str, text: str | ProgramFile, start: np.ndarray, options: ReadOptions) -> Any:
        checker = self.programs.checker if self.programs is not None else None  # large programs' check
        return prepare_job(name, text, self.config, start, options, self.planner_worker, self.store, checker)

    def _status(self) -> Steps[dict[str, Any]]:
        """The whole status for the status publisher, as a ``status`` request answers it,
        read in steps (fieldbus.cycle_slack: the publisher runs them in the cycle thread's slack)."""
        assert self.controller is not None
        return with_queue((yield from self.controller.status_steps()), self.programs)

    def _fast_status(self) -> Steps[dict[str, Any]]:
        """The status fields that move with the machine (controller.FAST_FIELDS), likewise."""
        assert self.controller is not None
        return (yield from self.controller.status_steps(fast_only=True))

    def _handle(self, request: Request) -> dict[str, Any]:
        controller = self.controller
        if controller is None or self._closing and request.cmd not in ANSWERED_WHILE_CLOSING:
            raise Refused(request.cmd, "the daemon is shutting down")
        return dispatch(controller, request, self.programs)

    def close(self) -> None:
        self._closing = True
        sd_notify("STOPPING=1")
        self._stop_programs()
        if self.controller is not None:
            self.controller.shutdown()  # the socket still answers status and job meanwhile
        if self.server is not None:
            self.server.close()
            self.server = None
        self._stop_hub()
        served = self.controller is not None
        self.controller = None
        self._stop_simulation()
        self._stop_planner_worker()
        if served:  # a start-up that failed has said so in its error already
            log.info(kv("daemon_stopped"))
        self.ownership.release()

    def _stop_hub(self) -> None:
        if self._stop_webhooks is not None:
            self._stop_webhooks()
            self._stop_webhooks = None
        if self._detach_event_log is not None:
            self._detach_event_log()
            self._detach_event_log = None
        if self.hub is not None:
            self.hub.close()
            self.hub = None

    def _stop_programs(self) -> None:
        """The queue starts nothing more; the checker process ends."""
        if self.programs is not None:
            self.programs.close()
            self.programs = None

    def _stop_motion(self) -> None:
        self._stop_programs()
        self._stop_hub()
        if self.controller is not None:
            self.controller.shutdown()
            self.controller = None
        self._stop_simulation()
        self._stop_planner_worker()

    def _stop_planner_worker(self) -> None:
        if self.planner_worker is not None:
            self.planner_worker.close()
            self.planner_worker = None

    def _stop_simulation(self) -> None:
        if self.simulation is not None:
            self.simulation.stop()
            self.simulation = None


def run_daemon(config: MachineConfig) -> int:
    """Serve until SIGTERM or SIGINT, then stop in order (module docstring); exit code 0. The
    process's threads that are not SCHED_FIFO stay off the real-time CPU
    (runtime.reserve_realtime_cpu)."""
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        log.info(kv("signal", name=signal.Signals(signum).name))
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    split = reserve_realtime_cpu()  # before any thread of ours starts: they inherit it
    daemon = Daemon(config)
    try:
        daemon.start()
        log.info(kv("cpus", realtime="none" if split is None else split.realtime,
                    normal="all" if split is None else ",".join(map(str, sorted(split.normal)))))
        while not stop.wait(0.5):
            pass
    finally:
        daemon.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
