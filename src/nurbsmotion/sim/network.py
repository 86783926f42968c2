"""Simulated drives on one python-can bus: the canopen Network (receive thread) and the
ticker thread (heartbeats, timed fault injections) they share."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen

from nurbsmotion.errors import InputError
from nurbsmotion.log import kv
from nurbsmotion.runtime import set_thread_realtime
from nurbsmotion.sim.drive import SimDrive
from nurbsmotion.sim.faults import FaultInjection
from nurbsmotion.sim.homing import HomeSensors
from nurbsmotion.sim.io_node import SimIoNode
from nurbsmotion.can.socketcan_batch import BatchedSocketcanBus, BatchNotifier
from nurbsmotion.sim.timing import SyncSettings
from nurbsmotion.chunked_file import write_file
from nurbsmotion.steps import Steps, drained

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Table:
    """One recording file: its path and its text in encoded chunks (recording.csv_chunks)."""

    path: Path
    chunks: list[bytes]


def write_tables(tables: list[Table]) -> list[Path]:
    """Write each table (chunked_file: one system call a chunk); their paths."""
    return [write_file(t.path, t.chunks) for t in tables]

# The receive thread's read timeout: how long stop() waits for it at most (canopen: 1 s).
NOTIFIER_CYCLE_S = 0.1


UNLIMITED_VELOCITY_COUNTS_S = math.inf


class DriveSetupError(ValueError):
    """A drive of axis ``axis_index`` could not be built (e.g. its EDS does not load)."""

    def __init__(self, axis_index: int, message: str) -> None:
        super().__init__(message)
        self.axis_index = axis_index
        self.message = message


@dataclass(frozen=True)
class IoInput:
    """A named input of a simulated I/O node: its bit and whether its wire reads 0 when active."""

    node_id: int
    bit: int
    active_low: bool = False


@dataclass(frozen=True)
class SpindleSim:
    """A spindle drive to simulate: the packaged CiA-402 drive (or ``eds``) at ``node_id``,
    used in profile velocity (3) or cyclic synchronous velocity (9) mode."""

    node_id: int
    counts_per_rev: float
    eds: str | Path | None = None

    def rpm(self, velocity_counts_s: float) -> float:
        """rev/min = counts/s · 60 / counts_per_rev."""
        return velocity_counts_s * 60.0 / self.counts_per_rev


def machine_spindle(machine: Any) -> SpindleSim | None:
    """The spindle drive of a configuration's ``spindle`` section (None: 'none' or absent)."""
    spindle: Any = getattr(machine, "spindle", None)
    if spindle is None or not hasattr(spindle, "node_id"):
        return None
    return SpindleSim(spindle.node_id, spindle.counts_per_rev, spindle.eds)


class SimNetwork:
    """Any number of :class:`SimDrive` and :class:`SimIoNode` on one bus
    (``interface``/``channel`` as python-can).

    Use as a context manager or call :meth:`start` / :meth:`stop`. Nodes added after start
    boot at once.
    """

    def __init__(self, interface: str = "virtual", channel: str = "nurbsmotion", bitrate: int = 1_000_000, **bus_kwargs: Any) -> None:
        self.interface = interface
        self.channel = channel
        self.bitrate = bitrate
        self.bus_kwargs = bus_kwargs
        self.drives: dict[int, SimDrive] = {}
        self.io_nodes: dict[int, SimIoNode] = {}
        self.io_inputs: dict[str, IoInput] = {}  # named inputs (from a machine's io section)
        self.spindle: SpindleSim | None = None
        self.network: canopen.Network | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._ticker: threading.Thread | None = None
        self.started_at = time.monotonic()
        self.rx_batch = True  # SocketCAN: read every waiting frame per wake-up (nurbsmotion/can/socketcan_batch.py)
        # SCHED_FIFO priority of the drives' receive and ticker threads (None: normal). For drives
        # sharing a process with a SCHED_FIFO master (the daemon with simulate: true): a real
        # drive has its own CPU, so its SYNC/RPDO handling and heartbeat never wait behind the
        # host's other processes; a normal thread preempted while it holds the GIL or a drive's
        # lock stalls every thread of the process, master included (docs/daemon.md).
        self.rt_priority: int | None = None
        self.thread_policy: dict[str, str] = {}  # 'receive' / 'ticker' -> policy in force (rt_priority set)

    def add_drive(self, node_id: int, eds: str | Path | None = None, **drive_kwargs: Any) -> SimDrive:
        """Create drive ``node_id`` (keyword arguments as :class:`SimDrive`)."""
        self._check_free(node_id)
        drive = SimDrive(node_id, eds, **drive_kwargs)
        self.drives[node_id] = drive
        if self.network is not None:
            drive.attach(self.network)
            self._wake.set()
        return drive

    def add_io_node(self, node_id: int, input_groups: int = 1, output_groups: int = 1) -> SimIoNode:
        """Create CiA-401 node ``node_id`` (8 inputs / outputs per group)."""
        self._check_free(node_id)
        node = SimIoNode(node_id, input_groups, output_groups)
        self.io_nodes[node_id] = node
        if self.network is not None:
            node.attach(self.network)
            self._wake.set()
        return node

    def set_io_input(self, name: str, active: bool) -> None:
        """Press / release the named input (e.g. ``estop``): the wire reads ``active`` XOR
        ``active_low``; the node sends its TPDO as it is configured to."""
        signal = self.io_inputs.get(name)
        if signal is None:
            raise InputError(f"input {name!r}", f"no such simulated input (have {sorted(self.io_inputs)})")
        self.io_nodes[signal.node_id].set_input(signal.bit, active != signal.active_low)

    def _check_free(self, node_id: int) -> None:
        if node_id in self.drives or node_id in self.io_nodes:
            raise ValueError(f"node {node_id} is already simulated")

    @classmethod
    def for_machine(
        cls, machine: Any, *, lag_cycles: int = 1, max_velocity_counts_s: float | None = None, record: bool = True,
        sync: SyncSettings | None = None, home_sensors: dict[int, HomeSensors] | None = None,
        spindle: SpindleSim | None = None,
    ) -> "SimNetwork":
        """One drive per axis of a ``nurbsmotion.config.MachineConfig`` (read by attribute:
        bus.interface/channel/bitrate, axes[].name/node_id/eds/identity), and the CiA-401 node
        of its ``io`` section if it has one (io.node_id, io.inputs[].name/bit/active_low,
        input_groups, output_groups), every input inactive at start.

        Each drive is its EDS straight out of the box (plus the axis identity in 0x1018):
        mode, cycle period and everything else are what the master writes, so a missing
        write shows. ``sync`` sets hold/extrapolate and the sync-loss fault of every drive;
        ``home_sensors`` {node id: HomeSensors} the switches and index pulses homing finds;
        an axis' ``homing.home_offset_object`` / ``home_offset_sign`` say what its vendor
        object does (SimDrive ``home_object``: an EDS does not say);
        ``spindle`` adds a spindle drive (its node id must be free); without it, the machine's
        own ``spindle`` section if it describes a drive (node_id, counts_per_rev, eds).
        """
        bus = machine.bus
        net = cls(interface=bus.interface, channel=bus.channel, bitrate=bus.bitrate)
        sensors = home_sensors or {}
        unknown = sorted(set(sensors) - {axis.node_id for axis in machine.axes})
        if unknown:
            raise InputError("home sensors", f"node {unknown[0]} is not an axis of the configuration")
        for axis_index, axis in enumerate(machine.axes):
            identity = (axis.identity.vendor_id, axis.identity.product_code) if axis.identity else None
            try:
                net.add_drive(
                    axis.node_id,
                    axis.eds,
                    lag_cycles=lag_cycles,
                    max_velocity_counts_s=max_velocity_counts_s or UNLIMITED_VELOCITY_COUNTS_S,
                    identity=identity,
                    record=record,
                    name=f"{axis.name}/node{axis.node_id}",
                    sync=sync,
                    home_sensors=sensors.get(axis.node_id),
                    home_object=_home_object(axis),
                )
            except Exception as err:  # noqa: BLE001 - canopen raises many kinds for a bad EDS
                raise DriveSetupError(axis_index, f"cannot simulate axis {axis.name}: {type(err).__name__}: {err}") from err
        io = getattr(machine, "io", None)
        if io is not None:
            net._add_machine_io(io)
        spindle = spindle or machine_spindle(machine)
        if spindle is not None:
            net.add_spindle(spindle, record=record, sync=sync)
        return net

    def add_spindle(self, spindle: SpindleSim, **drive_kwargs: Any) -> SimDrive:
        """Create the spindle drive (keyword arguments as :class:`SimDrive`)."""
        if not spindle.counts_per_rev > 0:
            raise InputError("spindle", f"counts_per_rev must be > 0, got {spindle.counts_per_rev}")
        if spindle.node_id in self.drives or spindle.node_id in self.io_nodes:
            raise InputError("spindle", f"node {spindle.node_id} is already simulated (an axis or the io node)")
        drive = self.add_drive(spindle.node_id, spindle.eds, name=f"spindle/node{spindle.node_id}", **drive_kwargs)
        self.spindle = spindle
        return drive

    def _add_machine_io(self, io: Any) -> None:
        """The io section's node, with its named inputs all inactive (active-low wires at 1)."""
        node = self.add_io_node(io.node_id, io.input_groups, io.output_groups)
        for signal in io.inputs:
            self.io_inputs[signal.name] = IoInput(io.node_id, signal.bit, signal.active_low)
            if signal.active_low:
                node.set_input(signal.bit, True)

    def __getitem__(self, node_id: int) -> SimDrive:
        return self.drives[node_id]

    def start(self) -> "SimNetwork":
        """Open the bus, boot every drive (boot-up messages) and start the heartbeats.
        A bus that cannot be opened raises OSError or can.CanError and starts nothing."""
        if self.network is not None:
            return self
        network = canopen.Network()
        network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        if self.interface == "socketcan":  # a batch of frames per wake-up (nurbsmotion/can/socketcan_batch.py)
            network.bus = BatchedSocketcanBus(channel=self.channel, batch=self.rx_batch, **self.bus_kwargs)
        else:
            network.bus = can.Bus(interface=self.interface, channel=self.channel, bitrate=self.bitrate,
                                  **self.bus_kwargs)
        # what canopen's connect() does once the bus is set, with the receive thread's priority
        network.notifier = BatchNotifier(network.bus, network.listeners, network.NOTIFIER_CYCLE,
                                         on_thread_start=self._realtime_thread("receive"))
        self.network = network
        self.started_at = time.monotonic()
        for drive in self.drives.values():
            drive.attach(network)
        for io_node in self.io_nodes.values():
            io_node.attach(network)
        self._stop.clear()
        self._ticker = threading.Thread(target=self._tick_loop, name="sim-ticker", daemon=True)
        self._ticker.start()
        log.info(kv("sim.start", interface=self.interface, channel=self.channel, nodes=sorted(self.drives),
                    io_nodes=sorted(self.io_nodes)))
        return self

    def stop(self) -> None:
        """Stop heartbeats and timers, detach the drives, close the bus."""
        self._stop.set()
        self._wake.set()
        if self._ticker is not None:
            self._ticker.join(timeout=2.0)
            self._ticker = None
        for drive in self.drives.values():
            drive.detach()
        for io_node in self.io_nodes.values():
            io_node.detach()
        if self.network is not None:
            self._log_receive_lag()
            self.network.disconnect()
            self.network = None
        log.info(kv("sim.stop", channel=self.channel))

    def _log_receive_lag(self) -> None:
        """One line: how far behind the wire the drives' process read (SocketCAN only)."""
        bus = self.network.bus if self.network is not None else None
        if isinstance(bus, BatchedSocketcanBus) and bus.lag.wakeups:
            log.info(kv("sim.rx", **bus.lag.figures()))

    def __enter__(self) -> "SimNetwork":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def inject(self, fault: FaultInjection) -> None:
        """Route ``fault`` to the drive ``fault.node_id``."""
        drive = self.drives.get(fault.node_id) if fault.node_id is not None else None
        if drive is None:
            raise InputError(f"node {fault.node_id}", f"no simulated drive with this node id (have {sorted(self.drives)})")
        drive.inject(fault)
        self._wake.set()

    def write_recordings(self, directory: str | Path, timelines: bool = False) -> list[Path]:
        """Write ``<dir>/node<id>.csv`` (applied set-points) for every drive, and with
        ``timelines`` ``<dir>/node<id>.sync.csv`` (every SYNC); returns the paths."""
        return write_tables(drained(self.recording_steps(directory, timelines), lambda _: None))

    def recording_steps(self, directory: str | Path, timelines: bool = False) -> Steps[list[Table]]:
        """The files of :meth:`write_recordings`, formatted in short steps
        (recording.CSV_ROWS_PER_STEP rows each); ``write_tables`` writes them."""
        directory = Path(directory)
        tables = []
        for node_id, drive in sorted(self.drives.items()):
            tables.append(Table(directory / f"node{node_id}.csv", (yield from drive.recorder.csv_chunks())))
            if timelines:
                tables.append(Table(directory / f"node{node_id}.sync.csv", (yield from drive.timeline.csv_chunks())))
        return tables

    def _realtime_thread(self, name: str) -> Callable[[], None]:
        """Make the calling thread SCHED_FIFO rt_priority (when set) and note its policy."""
        def make_realtime() -> None:
            if self.rt_priority is not None:
                self.thread_policy[name] = set_thread_realtime(self.rt_priority)
                log.info(kv("sim.thread_priority", thread=name, policy=self.thread_policy[name],
                            priority=self.rt_priority))
        return make_realtime

    def _tick_loop(self) -> None:
        self._realtime_thread("ticker")()
        while not self._stop.is_set():
            wait_s = 0.05
            for drive in list(self.drives.values()):
                try:
                    wait_s = min(wait_s, drive.tick() - drive.now())  # each drive on its own clock
                except Exception:  # noqa: BLE001 - one drive's error must not stop the others' heartbeat
                    log.exception("sim ticker: node %d", drive.node_id)
            for io_node in list(self.io_nodes.values()):
                try:
                    now = time.monotonic()
                    wait_s = min(wait_s, io_node.tick(now) - now)
                except Exception:  # noqa: BLE001 - as for drives
                    log.exception("sim ticker: I/O node %d", io_node.node_id)
            self._wake.wait(max(wait_s, 0.0))
            self._wake.clear()


def _home_object(axis: Any) -> tuple[int, int] | None:
    """(index, sign) of the vendor object an axis' homing names for its offset, else None."""
    homing = getattr(axis, "homing", None)
    index = getattr(homing, "home_offset_object", None)
    return None if index is None else (index, homing.home_offset_sign)  # type: ignore[union-attr]
