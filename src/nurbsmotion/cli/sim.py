"""``nurbsmotion sim``: simulated CiA-402 drives for a configuration's axes on its bus."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from nurbsmotion.config import MachineConfig, load_config
from nurbsmotion.errors import InputError
from nurbsmotion.log import kv, setup_logging
from nurbsmotion.sim import FaultInjection, SimNetwork, parse_fault_spec
from nurbsmotion.sim.homing import HomeSensors
from nurbsmotion.sim.machine_sensors import machine_home_sensors
from nurbsmotion.sim.network import SpindleSim
from nurbsmotion.sim.network import DriveSetupError
from nurbsmotion.sim.timing import MissingSetpoint, SyncSettings

HELP = "run simulated CiA-402 drives for the configuration's axes (and its io node) until SIGINT/SIGTERM"

log = logging.getLogger("nurbsmotion.sim.cli")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="machine configuration (YAML)")
    parser.add_argument("--record-dir", metavar="DIR", help="write each drive's applied set-points to DIR/node<id>.csv on exit")
    parser.add_argument(
        "--fault", action="append", default=[], metavar="SPEC",
        help="inject a fault, e.g. node=2,kind=fault,at_sync=500,code=0x2310 (repeatable; see docs/sim.md)",
    )
    parser.add_argument(
        "--home-sensors", action="append", default=[], metavar="SPEC",
        help="limit switches / index pulses a drive's homing finds, in raw counts, e.g. "
             "node=1,negative_limit=-2500,positive_limit=2500,index_pitch=1000,index_phase=300 (repeatable)",
    )
    parser.add_argument("--spindle", metavar="SPEC", default=None,
                        help="add a spindle drive (profile velocity 3 / cyclic synchronous velocity 9), "
                             "e.g. node=5,counts_per_rev=4096")
    parser.add_argument("--lag-cycles", type=int, default=1, metavar="N", help="servo lag in SYNC cycles (default 1)")
    parser.add_argument("--max-velocity-counts-s", type=float, default=None, metavar="V", help="servo velocity limit (default: none)")
    parser.add_argument("--missing-setpoint", default=MissingSetpoint.HOLD.value, metavar="hold|extrapolate",
                        help="what a drive does in a cycle without a fresh set-point (default hold)")
    parser.add_argument("--own-cycle", action="store_true",
                        help="drives run their own cycle locked onto SYNC: a late SYNC leaves cycles without one")
    parser.add_argument("--sync-loss-periods", type=float, default=None, metavar="N",
                        help="fault (EMCY 0x8700) when no SYNC came for N cycle periods while enabled (default: off)")
    parser.add_argument("--rt-priority", type=int, default=None, metavar="N",
                        help="run the drives' receive and ticker threads SCHED_FIFO N (1-99; needs root or "
                             "CAP_SYS_NICE, else they run normal and the log says why), as a drive has its own CPU "
                             "(default: normal priority)")


def parse_faults(specs: list[str], machine: MachineConfig) -> list[FaultInjection]:
    """Parse every ``--fault`` spec; each must name a node of the configuration."""
    nodes = {axis.node_id for axis in machine.axes}
    faults = []
    for text in specs:
        fault = parse_fault_spec(text)
        if fault.node_id is None:
            raise InputError(f"fault spec {text!r}", "node is required")
        if fault.node_id not in nodes:
            raise InputError(f"fault spec {text!r}", f"node {fault.node_id} is not an axis of {machine.source} (nodes {sorted(nodes)})")
        faults.append(fault)
    return faults


_SENSOR_KEYS = {"negative_limit": "negative_limit_counts", "positive_limit": "positive_limit_counts",
                "index_pitch": "index_pitch_counts", "index_phase": "index_phase_counts"}


def parse_home_sensors(specs: list[str], machine: MachineConfig) -> dict[int, HomeSensors]:
    """Parse every ``--home-sensors`` spec ({node id: HomeSensors}); each names one axis node once."""
    nodes = {axis.node_id for axis in machine.axes}
    sensors: dict[int, HomeSensors] = {}
    for text in specs:
        where = f"--home-sensors {text!r}"
        fields: dict[str, float] = {}
        node_id = None
        for part in text.split(","):
            key, sep, value = (t.strip() for t in part.partition("="))
            if not sep or not key or not value:
                raise InputError(where, f"expected key=value, got {part.strip()!r}")
            if key != "node" and key not in _SENSOR_KEYS:
                raise InputError(where, f"unknown key {key!r} (node, {', '.join(_SENSOR_KEYS)})")
            try:
                number = float(int(value, 0)) if key == "node" else float(value)
            except ValueError:
                raise InputError(where, f"{key}={value!r} is not a number") from None
            if key == "node":
                node_id = int(number)
            else:
                fields[_SENSOR_KEYS[key]] = number
        if node_id is None or node_id not in nodes:
            raise InputError(where, f"node must be an axis of {machine.source} (nodes {sorted(nodes)})")
        if node_id in sensors:
            raise InputError(where, f"node {node_id} given twice")
        if fields.get("index_pitch_counts", 1.0) <= 0:
            raise InputError(where, "index_pitch must be > 0")
        low, high = fields.get("negative_limit_counts"), fields.get("positive_limit_counts")
        if low is not None and high is not None and low >= high:
            raise InputError(where, f"negative_limit {low:g} must be below positive_limit {high:g}")
        sensors[node_id] = HomeSensors(**fields)
    return sensors


def parse_spindle(spec: str | None, machine: MachineConfig) -> SpindleSim | None:
    """``node=5,counts_per_rev=4096``: a spindle drive at a node no axis (or io) uses."""
    if spec is None:
        return None
    where = f"--spindle {spec!r}"
    fields: dict[str, str] = {}
    for part in spec.split(","):
        key, sep, value = (t.strip() for t in part.partition("="))
        if not sep or key not in ("node", "counts_per_rev") or not value:
            raise InputError(where, f"expected node=N,counts_per_rev=C, got {part.strip()!r}")
        fields[key] = value
    if set(fields) != {"node", "counts_per_rev"}:
        raise InputError(where, "node and counts_per_rev are both required")
    try:
        node_id, counts_per_rev = int(fields["node"], 0), float(fields["counts_per_rev"])
    except ValueError:
        raise InputError(where, "node and counts_per_rev must be numbers") from None
    used = {axis.node_id for axis in machine.axes} | ({machine.io.node_id} if machine.io is not None else set())
    if not 1 <= node_id <= 127 or node_id in used:
        raise InputError(where, f"node must be 1..127 and not an axis or io node of {machine.source} (used {sorted(used)})")
    if not counts_per_rev > 0:
        raise InputError(where, f"counts_per_rev must be > 0, got {counts_per_rev:g}")
    return SpindleSim(node_id, counts_per_rev)


def sync_settings(missing_setpoint: str, sync_loss_periods: float | None, own_cycle: bool = False) -> SyncSettings:
    if sync_loss_periods is not None and not sync_loss_periods >= 1:
        raise InputError("--sync-loss-periods", f"must be >= 1, got {sync_loss_periods}")
    choices = [m.value for m in MissingSetpoint]
    if missing_setpoint not in choices:
        raise InputError("--missing-setpoint", f"must be one of {', '.join(choices)}, got {missing_setpoint!r}")
    return SyncSettings(missing_setpoint=MissingSetpoint(missing_setpoint), own_cycle=own_cycle,
                        loss_periods=sync_loss_periods)


def check_options(lag_cycles: int, max_velocity_counts_s: float | None, record_dir: str | None,
                  rt_priority: int | None = None) -> None:
    if rt_priority is not None and not 1 <= rt_priority <= 99:
        raise InputError("--rt-priority", f"must be 1..99 (SCHED_FIFO), got {rt_priority}")
    if lag_cycles < 0:
        raise InputError("--lag-cycles", f"must be >= 0, got {lag_cycles}")
    if max_velocity_counts_s is not None and not max_velocity_counts_s > 0:
        raise InputError("--max-velocity-counts-s", f"must be > 0, got {max_velocity_counts_s}")
    if record_dir is not None:
        try:
            Path(record_dir).mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise InputError("--record-dir", f"cannot create {record_dir}: {err.strerror or err}") from None


def serve(
    machine: MachineConfig,
    faults: list[FaultInjection],
    stop: threading.Event,
    *,
    lag_cycles: int = 1,
    max_velocity_counts_s: float | None = None,
    record_dir: str | Path | None = None,
    on_ready: Callable[[SimNetwork], Any] | None = None,
    sync: SyncSettings | None = None,
    home_sensors: dict[int, HomeSensors] | None = None,
    spindle: SpindleSim | None = None,
    rt_priority: int | None = None,
) -> SimNetwork:
    """Run the drives until ``stop`` is set; then stop them and write the recordings
    (set-points and SYNC timelines are recorded only when ``record_dir`` is given).
    ``rt_priority``: SCHED_FIFO of the drives' threads (SimNetwork.rt_priority; None: normal)."""
    try:
        net = SimNetwork.for_machine(machine, lag_cycles=lag_cycles, max_velocity_counts_s=max_velocity_counts_s,
                                     record=record_dir is not None, sync=sync, home_sensors=home_sensors, spindle=spindle)
    except DriveSetupError as err:
        raise InputError(machine.where(f"axes[{err.axis_index}].eds"), err.message) from None
    net.rt_priority = rt_priority
    try:
        net.start()
    except (OSError, can.CanError) as err:
        raise InputError(machine.where("bus"), f"cannot open {net.interface} channel {net.channel}: {err}") from None
    try:
        for fault in faults:
            net.inject(fault)
        log.info(kv("sim.ready", interface=net.interface, channel=net.channel, nodes=sorted(net.drives),
                    io_nodes=sorted(net.io_nodes)))
        if on_ready is not None:
            on_ready(net)
        stop.wait()
    finally:
        net.stop()
        for node_id, drive in sorted(net.drives.items()):
            s = drive.stats
            log.info(kv("sim.summary", node=node_id, state=drive.state.name, syncs=s.syncs, setpoints=s.setpoints_applied,
                        rpdos=s.rpdos_received, dropped=s.rpdos_dropped, overwritten=s.rpdos_overwritten, emcys=s.emcys_sent,
                        late_syncs=s.syncs_late, missed_cycles=s.ticks_missed, missing_setpoints=s.setpoints_missing))
        if record_dir is not None:
            for path in net.write_recordings(record_dir, timelines=True):
                log.info(kv("sim.recording", path=str(path)))
    return net


def run(args: argparse.Namespace) -> int:
    machine = load_config(args.config)
    faults = parse_faults(args.fault, machine)
    home_sensors = {**machine_home_sensors(machine), **parse_home_sensors(args.home_sensors, machine)}
    spindle = parse_spindle(args.spindle, machine)
    check_options(args.lag_cycles, args.max_velocity_counts_s, args.record_dir, args.rt_priority)
    sync = sync_settings(args.missing_setpoint, args.sync_loss_periods, args.own_cycle)
    setup_logging(max(1, getattr(args, "verbose", 0)))  # a service: its INFO lines (sim.ready, faults) on stderr
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        serve(machine, faults, stop, lag_cycles=args.lag_cycles, max_velocity_counts_s=args.max_velocity_counts_s,
              record_dir=args.record_dir, sync=sync, home_sensors=home_sensors, spindle=spindle,
              rt_priority=args.rt_priority)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
