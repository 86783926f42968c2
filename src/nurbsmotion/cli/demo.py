"""``nurbsmotion demo``: the daemon and three simulated CiA-402 drives in this process on
python-can's virtual bus run Wang's Table 1 NURBS curve; prints what happened and where
the record and the plot are.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

from nurbsmotion import data
from nurbsmotion.cli.run import _display, follow
from nurbsmotion.config import AxisConfig, MachineConfig, load_config, parse_config
from nurbsmotion.service.client import Client, RequestFailed
from nurbsmotion.service.daemon import Daemon
from nurbsmotion.service.verify import drive_report

HELP = "run Wang's Table 1 curve on simulated drives (daemon + drives in this process) and report"
PROGRAM_NAME = "wang_table1.nc"


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
    return replace(config, data_dir=args.data_dir or config.data_dir, axes=_with_findable_eds(config.axes),
                   control=replace(config.control, socket=str(socket_path), group=None))


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
    try:
        config = demo_config(args, folder / "control.sock")
        daemon = Daemon(config)
        daemon.start()
        try:
            print(f"drives up: {len(config.axes)} simulated axes on {config.bus.interface}:{config.bus.channel}, "
                  f"T = {config.cycle_period_s * 1000:g} ms")
            info = _run_program(config, args.no_progress)
        finally:
            daemon.close()
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return _report(info, config)


def _run_program(config: MachineConfig, quiet: bool) -> dict[str, Any]:
    with Client(config.control.socket) as client:
        try:
            job = client.call("submit", name=PROGRAM_NAME, program=data.read_text(PROGRAM_NAME))["job"]
        except RequestFailed as err:
            from nurbsmotion.errors import InputError

            raise InputError(PROGRAM_NAME, "; ".join(err.errors)) from None
        plan = job["summary"]
        if plan.get("streamed"):  # planned while it runs (docs/daemon.md, streamed jobs)
            print(f"streaming {PROGRAM_NAME}: {plan['length_mm']:.1f} mm, {plan['blocks']} blocks, "
                  f"first chunk planned in {plan['first_chunk_s']:.2f} s ({plan['algorithm']})")
        else:
            print(f"planned {PROGRAM_NAME}: {plan['length_mm']:.1f} mm in {plan['cycles']} cycles "
                  f"({plan['duration_s']:.2f} s, {plan['algorithm']}, planning {plan['planning_time_s']:.2f} s)")
        display = _display(PROGRAM_NAME, quiet)
        try:
            return follow(client, job["id"], display.update if display else None)
        finally:
            if display is not None:
                display.close()


def _report(info: dict[str, Any], config: MachineConfig) -> int:
    folder = Path(info["folder"])
    outcome, plan = info["outcome"], info["plan"]
    measured = plan["measured"]
    drives = drive_report(folder, config)
    print(f"outcome: {outcome['outcome']}{': ' + outcome['reason'] if outcome.get('reason') else ''}")
    print(f"motion time: {plan['duration_s']:.3f} s planned, {outcome['motion_time_s']:.2f} s wall clock")
    print(f"max chord error: {measured['max_chord_error_mm'] * 1000:.2f} um "
          f"(limit {config.interpolation.chord_error_mm * 1000:g} um)")
    print(f"max acceleration: {measured['max_accel_mm_s2']:.0f} mm/s^2 "
          f"(limit {config.interpolation.max_accel_mm_s2:g} mm/s^2)")
    print(f"max following error: {drives.max_following_error_mm:.3f} mm (simulated servo)")
    print(f"set-points: {outcome['sent']} streamed of {outcome['planned']} planned; the drives applied "
          f"{'exactly the planned sequence' if drives.exact else 'a DIFFERENT sequence'}")
    print(f"cycles: {outcome['late_cycles']} late, {outcome['missed_cycles']} missed")
    plot = _plot(folder, config)
    print(f"record: {folder}")
    if plot:
        print(f"plot: {plot}")
    return 0 if outcome["outcome"] == "completed" and drives.exact else 1


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
    from nurbsmotion.planning.measure import measure
    from nurbsmotion.planning.plot import plot_run
    from nurbsmotion.planning.trace import read_trace
    from nurbsmotion.service.planner import parse

    plan = json.loads((folder / "plan.json").read_text(encoding="utf-8"))
    trace = read_trace(folder / "trace.csv")
    program = parse(PROGRAM_NAME, data.read_text(PROGRAM_NAME), np.zeros(3))
    trajectory = Trajectory(plan["algorithm"], plan["period_s"], trace["block"].astype(np.int32), trace["u"],
                            np.column_stack([trace["x"], trace["y"], trace["z"]]), trace["feed"])
    path = folder / "plot.png"
    plot_run(path, program, trajectory, measure(trajectory, program), limits_from_config(config))
    return path
