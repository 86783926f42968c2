"""``nurbsmotion demo``: the daemon and three simulated CiA-402 drives in this process on
python-can's virtual bus: the axes are homed (the simulated drives have a limit switch and
index pulses: X on its negative limit switch, method 17; Y on an index pulse, method 34;
Z where it stands, ``here``; an axis whose EDS offers no such homing: ``here``), jogged
(X+10) and moved by MDI, then run Wang's Table 1 NURBS curve; prints what happened and
where the record and the plot are.
"""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import sys
import tempfile
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import functools

from nurbsmotion import data
from nurbsmotion.cli._format import figure, number
from nurbsmotion.cli.run import _display, follow
from nurbsmotion.config import AxisConfig, MachineConfig, load_config, parse_config
from nurbsmotion.errors import Refused
from nurbsmotion.runtime import normal_again, realtime_for_normal_threads, unpin_threads
from nurbsmotion.service.client import Client, RequestFailed
from nurbsmotion.config.homing import HomingConfig
from nurbsmotion.service.daemon import Daemon
from nurbsmotion.service.link import open_link
from nurbsmotion.service.verify import drive_report

HELP = "run Wang's Table 1 curve on simulated drives (daemon + drives in this process) and report"
PROGRAM_NAME = "wang_table1.nc"
# The demo machine's homing, for axes whose configuration has none, and the switches and index
# pulses of its simulated drives (raw counts at power-on; 1000 counts/mm in config/demo.yaml).
DEMO_HOMING = {
    "X": HomingConfig(method=17, speed_search_mm_s=20, speed_zero_mm_s=2, accel_mm_s2=200, offset_mm=-20, order=2),
    "Y": HomingConfig(method=34, speed_search_mm_s=20, speed_zero_mm_s=2, accel_mm_s2=200, offset_mm=0, order=1),
    "Z": HomingConfig(method="here", offset_mm=0),
}
DEMO_SENSORS = {"X": {"negative_limit_counts": -20_000}, "Y": {"index_pitch_counts": 4000, "index_phase_counts": 1500}}
DEMO_JOG = {"axis": "X", "distance": 10.0, "speed": 20.0}
# The simulated drives and the master are SCHED_FIFO threads of this process; every other
# thread (this one, the control server's, the job watchers) runs SCHED_FIFO at the lowest
# priority while they run, so that none holds the interpreter lock while the host's other
# work keeps it off the CPU: all the drives' heartbeats stalled together 330-670 ms on a
# loaded host, a fault (docs/reliability.md, "The demo under heavy load").
DEMO_THREADS_PRIORITY = 1
ENDING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
DEMO_MDI = "G01 X5 Y5 F3000"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="machine configuration (default: the packaged demo.yaml, "
                                                         "a copy of config/demo.yaml); must have simulate: true")
    parser.add_argument("--data-dir", metavar="DIR", help="where the job record goes (default: the config's "
                                                          "data_dir, var/demo for the demo config)")
    parser.add_argument("--no-progress", action="store_true", help="no progress display")


def demo_config(args: argparse.Namespace, socket_path: Path) -> MachineConfig:
    config = load_config(args.config) if args.config else parse_config(data.read_text("demo.yaml"), "demo.yaml")
    if not config.simulate:
        from nurbsmotion.errors import InputError

        raise InputError(config.where("simulate"), "the demo runs simulated drives: set simulate: true")
    from nurbsmotion.fieldbus.homing_check import offered_homing  # a drive whose EDS lacks the homing: 'here'

    axes = tuple(a if a.homing or a.name not in DEMO_HOMING else replace(a, homing=offered_homing(a, DEMO_HOMING[a.name]))
                 for a in _with_findable_eds(config.axes))
    return replace(config, data_dir=args.data_dir or config.data_dir, axes=axes,
                   control=replace(config.control, socket=str(socket_path), group=None))


def demo_sensors(config: MachineConfig) -> dict[int, Any]:
    """The simulated drives' home switches and index pulses (sim.homing.HomeSensors) by node."""
    from nurbsmotion.sim.homing import HomeSensors

    return {a.node_id: HomeSensors(**DEMO_SENSORS[a.name]) for a in config.axes if a.name in DEMO_SENSORS}


def _with_findable_eds(axes: tuple[AxisConfig, ...]) -> tuple[AxisConfig, ...]:
    """Axes without an EDS use the simulated drives' default (the repository's eds/); in a
    non-editable install that folder is absent, so use the packaged copy."""
    from nurbsmotion.sim import default_eds_path

    try:
        default_eds_path()
        return axes
    except FileNotFoundError:
        eds = str(data.path("nurbsmotion-servo.eds"))
        return tuple(a if a.eds else replace(a, eds=eds) for a in axes)


def run(args: argparse.Namespace) -> int:
    folder = Path(tempfile.mkdtemp(prefix="nurbsmotion-demo-"))
    previous = _end_like_ctrl_c(ENDING_SIGNALS)
    try:
        config = demo_config(args, folder / "control.sock")
        daemon = Daemon(config, functools.partial(open_link, home_sensors=demo_sensors(config)))
        raised: list[int] = []
        try:
            daemon.start()
            raised = realtime_for_normal_threads(DEMO_THREADS_PRIORITY)
            unpin_threads()  # the simulated drives may use the other CPU when another process' threads hold the last
            print(f"drives up: {len(config.axes)} simulated axes on {config.bus.interface}:{config.bus.channel}, "
                  f"T = {config.cycle_period_s * 1000:g} ms")
            _home_jog_mdi(config)
            info = _run_program(config, args.no_progress, daemon)
        finally:
            daemon.close()
            normal_again(raised)  # the report and the plot take CPU seconds: not at a real-time priority
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return _report(info, config)


def _end_like_ctrl_c(signals: tuple[signal.Signals, ...]) -> dict[signal.Signals, Any]:
    """While the demo's daemon runs, ``signals`` end it as Ctrl-C does (KeyboardInterrupt
    naming the signal): the job stopped on its path, every record with its outcome, the
    socket's folder removed. Left at their default, SIGTERM (``timeout``, ``kill``) and SIGHUP
    (the terminal closed) ended the process at once: a job folder without outcome and the
    folder left in the temporary directory. The handlers before, to restore; none outside
    the main thread (only it may set them)."""
    if threading.current_thread() is not threading.main_thread():
        return {}

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)

    return {sig: signal.signal(sig, interrupt) for sig in signals}


def _home_jog_mdi(config: MachineConfig) -> None:
    """Home every axis, jog X+10, one MDI line: each through the control API as a client would."""
    from nurbsmotion.cli.home import follow_homing
    from nurbsmotion.errors import InputError
    from nurbsmotion.config.homing import homing_method_name

    with Client(config.control.socket) as client:
        names = client.call("home")["axes"]
        print(f"homing {', '.join(names)} (simulated limit switch and index pulses)")
        homing = follow_homing_quietly(client, names, follow_homing)
        if homing["error"]:
            raise InputError("demo: home", homing["error"])
        positions = {a["name"]: a["actual_mm"] for a in client.call("status")["axes"]}
        for axis in config.axes:
            if axis.homing is not None:
                print(f"  axis {axis.name}: homed by {homing_method_name(axis.homing.method)}, "
                      f"now at {positions[axis.name]:.3f} mm")
        for title, cmd, fields in ((f"jog X+{DEMO_JOG['distance']:g} at {DEMO_JOG['speed']:g} mm/s", "jog", DEMO_JOG),
                                   (f"MDI {DEMO_MDI}", "mdi", {"text": DEMO_MDI})):
            job = client.call(cmd, **fields)["job"]
            info = follow(client, job["id"], None)
            outcome = info["outcome"]
            if outcome["outcome"] != "completed":
                raise InputError(f"demo: {title}", f"{outcome['outcome']}: {outcome['reason']}")
            end = {name: v["commanded_mm"] for name, v in outcome["final_position"].items()}
            print(f"{title}: completed, axes at " + " ".join(f"{n}{v:.3f}" for n, v in end.items()))


def follow_homing_quietly(client: Client, names: list[str], follow_homing: Any) -> dict[str, Any]:
    """cli.home's follow, its per-axis lines left out (the demo prints its own)."""
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):
        return follow_homing(client, names)


def _run_program(config: MachineConfig, quiet: bool, daemon: Daemon) -> dict[str, Any]:
    with Client(config.control.socket) as client:
        try:
            job = client.call("submit", name=PROGRAM_NAME, program=data.read_text(PROGRAM_NAME))["job"]
        except RequestFailed as err:
            from nurbsmotion.errors import InputError

            raise InputError(PROGRAM_NAME, "; ".join(err.errors)) from None
        try:
            print(plan_line(job["summary"]))
            display = _display(PROGRAM_NAME, quiet)
            try:
                return follow(client, job["id"], display.update if display else None)
            finally:
                if display is not None:
                    display.close()
        except BaseException as err:
            _stop_failed_job(daemon, job, err)
            raise


def plan_line(plan: dict[str, Any]) -> str:
    """The submitted job's plan in one line; a streamed job's length, cycles and duration are
    null until the planner worker has reached them (docs/daemon.md, streamed jobs)."""
    if plan.get("streamed"):
        return (f"planned {PROGRAM_NAME} while it runs: {figure(plan.get('length_mm'), '.1f', ' mm')}, "
                f"{plan['blocks']} blocks, first chunk in {number(plan.get('first_chunk_s'), 2)} s "
                f"({plan['algorithm']}, streamed)")
    return (f"planned {PROGRAM_NAME}: {figure(plan.get('length_mm'), '.1f', ' mm')} in {figure(plan.get('cycles'))} "
            f"cycles ({number(plan.get('duration_s'), 2)} s, {plan['algorithm']}, "
            f"planning {number(plan.get('planning_time_s'), 2)} s)")


def _stop_failed_job(daemon: Daemon, job: dict[str, Any], err: BaseException) -> None:
    """The demo failed (or was interrupted) while its job runs: stop the job along the path
    with a reason that says so, not the daemon's "asked to end", and name its record."""
    why = f"was interrupted ({err or 'Ctrl-C'})" if isinstance(err, KeyboardInterrupt) else \
        f"failed: {type(err).__name__}: {err}"
    controller = daemon.controller
    if controller is None:
        return
    try:
        controller.stop(f"stopped: the demo {why}")
    except Refused:  # it had ended already
        return
    sys.stderr.write(f"nurbsmotion demo: job {job['id']} stopped; its record: {job['folder']}\n")


def _report(info: dict[str, Any], config: MachineConfig) -> int:
    folder = Path(info["folder"])
    outcome, plan = info["outcome"], info["plan"]
    measured = plan.get("measured") or {}  # null when the planner worker ended before measuring
    chord_um = measured.get("max_chord_error_mm")
    drives = drive_report(folder, config)
    print(f"outcome: {outcome['outcome']}{': ' + outcome['reason'] if outcome.get('reason') else ''}")
    print(f"motion time: {number(plan.get('duration_s'), 3)} s planned, {number(outcome.get('motion_time_s'), 2)} s "
          f"wall clock")
    print(f"max chord error: {number(None if chord_um is None else chord_um * 1000, 2)} um "
          f"(limit {config.interpolation.chord_error_mm * 1000:g} um)")
    print(f"max acceleration: {number(measured.get('max_accel_mm_s2'), 0)} mm/s^2 "
          f"(limit {config.interpolation.max_accel_mm_s2:g} mm/s^2)")
    print(f"max following error: {drives.max_following_error_mm:.3f} mm (simulated servo)")
    print(f"set-points: {outcome['sent']} streamed of {outcome['planned']} planned; the drives applied "
          f"{'exactly the planned sequence' if drives.exact else 'a DIFFERENT sequence'}"
          f"{waited_text(drives.rest_waits, config.cycle_period_s)}")
    print(f"cycles: {figure(outcome.get('late_cycles'))} late, {figure(outcome.get('missed_cycles'))} missed")
    plot = _plot(folder, config)
    print(f"record: {folder}")
    if plot:
        print(f"plot: {plot}")
    return 0 if outcome["outcome"] == "completed" and drives.exact else 1


def waited_text(rest_waits: int, period_s: float) -> str:
    """Where the drives held at a rest of the plan for the planner's next chunk (streamed job)."""
    return f" (held {rest_waits} cycles, {rest_waits * period_s:.2f} s, at a rest of the plan for its next chunk)" \
        if rest_waits else ""


def _plot(folder: Path, config: MachineConfig) -> Path | None:
    """The six-panel figure of the run (planning.plot) from the job record, as plot.png in
    the record; None when matplotlib is missing (the demo extra installs it)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return None
    import numpy as np

    from nurbsmotion.planning.limits import limits_from_config
    from nurbsmotion.planning import Trajectory
    from nurbsmotion.planning.lookahead.planned_path import PlannedPath
    from nurbsmotion.planning.measure import measure
    from nurbsmotion.planning.plot import plot_run
    from nurbsmotion.planning.trace import read_trace
    from nurbsmotion.service.job_common import parse

    plan = json.loads((folder / "plan.json").read_text(encoding="utf-8"))
    trace = read_trace(folder / "trace.csv")
    program = parse(PROGRAM_NAME, data.read_text(PROGRAM_NAME), np.array(plan["start_mm"]))  # where the job started
    trajectory = Trajectory(plan["algorithm"], plan["period_s"], trace["block"].astype(np.int32), trace["u"],
                            np.column_stack([trace["x"], trace["y"], trace["z"]]), trace["feed"])
    path = folder / "plot.png"
    planned = PlannedPath.for_algorithm(program, limits_from_config(config), plan["algorithm"])
    plot_run(path, program, trajectory, measure(planned.rows(trajectory), planned.program), limits_from_config(config))
    return path
